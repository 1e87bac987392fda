"""Maximum-likelihood fit of the proportional-odds cumulative logit model on one factor, by Newton-Raphson.

The model (R ``ordinal::clm``'s parameterisation, treatment coding, the first level as reference):
``logit P(Y ≤ j | level l) = θ_j − β_l`` with ``β_0 = 0``. With one factor the likelihood depends on the data only
through the levels × categories table of counts, so the fit works on that table: a Likert question answered by 12
people under 5 conditions is at most 5 × 7 cells, whatever the number of answers.

Why our own fit: a power analysis fits this model thousands of times (seed 001's plan, five times per replicate).
statsmodels' ``OrderedModel`` maximises with BFGS on numerical gradients (~300 likelihood calls, ~75 ms a fit);
here the gradient and Hessian are analytic and Newton takes ~6 steps (as ``clm`` does). The log-likelihood is concave
in (θ, β) for the logistic (Pratt 1981), so Newton with step halving climbs to the maximum from the thresholds-only
start.

Numerics. A cell's probability ``p = F(a) − F(b)`` (``a = θ_c − β_l``, ``b = θ_{c−1} − β_l``) is computed as
``F(a) · (1 − F(b)) · (−expm1(b − a))`` — the same number without the cancellation of subtracting two values near 1
(or near 0) far out in a tail; its log is ``−log1p(e^−a) − log1p(e^b) + log(−expm1(b − a))``. Its derivatives are the
ratios ``f(a)/p`` and ``f(b)/p`` written in the same factors, so no cell underflows to 0/0.

Separation (a level whose answers all sit beyond another's, e.g. every answer at the scale's end): the maximum is at
infinity. The log-likelihood still rises to its supremum, which is what the likelihood-ratio test needs; the fit stops
when its gain is at rounding level and reports ``separated`` — some |β| past :data:`SEPARATED_BETA` still growing
by about 1 a Newton step (at a finite maximum the last steps shrink quadratically, so a finite but extreme
estimate, 2·ln(10⁶) for a 2 × 2 table of 10⁶ vs 1 answers, is not mistaken for one) — and no covariance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import expit

from studyctl.errors import StatsInputError

#: Newton steps at most (a regular fit takes 4-8; one with separation ~40, each adding ~1 to the diverging β).
MAX_STEPS = 200
#: Largest gradient component of a converged fit (as R's clm.control(gradTol = 1e-10) for the reference values).
GRAD_TOL = 1e-10
#: A fit is separated (an estimate is infinite; the fit stopped on the way there) when some |β| is past
#: SEPARATED_BETA (an odds ratio over e^20) and the last Newton step still moved a β by more than SEPARATED_STEP.
SEPARATED_BETA = 20.0
SEPARATED_STEP = 1e-2


@dataclass(frozen=True)
class CumulativeLogitFit:
    """The fitted model: ``coef`` (β of the levels after the first), ``thresholds`` (θ, increasing),
    ``llf`` (log-likelihood), ``cov`` (covariance of (θ, β) from the observed information; None when the
    estimates are infinite or the information is singular), ``steps`` (Newton steps), ``converged``
    (the gradient or the gain fell to rounding level within :data:`MAX_STEPS`), ``separated``."""

    coef: np.ndarray
    thresholds: np.ndarray
    llf: float
    cov: np.ndarray | None
    steps: int
    converged: bool
    separated: bool

    @property
    def coef_cov(self) -> np.ndarray | None:
        """The covariance block of the coefficients β (None when ``cov`` is)."""
        if self.cov is None:
            return None
        k = len(self.thresholds)
        return self.cov[k:, k:]


def null_llf(counts_by_category: np.ndarray) -> float:
    """Log-likelihood of the thresholds-only model (closed form: the categories' proportions)."""
    n = np.asarray(counts_by_category, dtype=float)
    n = n[n > 0]
    return float((n * np.log(n / n.sum())).sum())


class _Cells:
    """The table's non-empty cells as the linear maps (θ, β) → a and → b, with their counts."""

    def __init__(self, counts: np.ndarray) -> None:
        levels, cats = counts.shape
        self.n_theta = cats - 1
        size = self.n_theta + levels - 1
        ll, cc = np.nonzero(counts)
        self.n = counts[ll, cc].astype(float)
        rows = np.arange(ll.size)
        # a = θ_c − β_l (row of A), +∞ for the top category; b = θ_{c−1} − β_l, −∞ for the bottom one
        self.A = np.zeros((ll.size, size))
        self.B = np.zeros((ll.size, size))
        top, bottom = cc == cats - 1, cc == 0
        self.A[rows[~top], cc[~top]] = 1.0
        self.B[rows[~bottom], cc[~bottom] - 1] = 1.0
        with_beta = ll > 0
        self.A[rows[with_beta & ~top], self.n_theta + ll[with_beta & ~top] - 1] = -1.0
        self.B[rows[with_beta & ~bottom], self.n_theta + ll[with_beta & ~bottom] - 1] = -1.0
        self.top, self.bottom = top, bottom

    def ends(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = np.where(self.top, np.inf, self.A @ params)
        b = np.where(self.bottom, -np.inf, self.B @ params)
        return a, b

    def llf(self, params: np.ndarray) -> float:
        a, b = self.ends(params)
        if np.any(a <= b):  # thresholds out of order: outside the model
            return -math.inf
        logp = -np.logaddexp(0.0, -a) - np.logaddexp(0.0, b) + np.log(-np.expm1(b - a))
        return float(self.n @ logp)

    def derivatives(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gradient and Hessian of the log-likelihood at ``params`` (thresholds in order)."""
        a, b = self.ends(params)
        q = -np.expm1(b - a)
        ga = expit(-a) / (expit(-b) * q)  # f(a)/p
        gb = -expit(b) / (expit(a) * q)  # −f(b)/p
        # d²log p: f'(z) = f(z) (1 − 2F(z)) = f(z) tanh(−z/2)
        gaa = ga * np.tanh(-a / 2) - ga * ga
        gbb = gb * np.tanh(-b / 2) - gb * gb
        gab = -ga * gb
        n = self.n
        grad = self.A.T @ (n * ga) + self.B.T @ (n * gb)
        cross = (self.A.T * (n * gab)) @ self.B
        hess = (self.A.T * (n * gaa)) @ self.A + (self.B.T * (n * gbb)) @ self.B + cross + cross.T
        return grad, hess


def _start(counts: np.ndarray) -> np.ndarray:
    """The thresholds-only maximum (θ_j = logit of the cumulative proportion, β = 0): inside the model."""
    by_cat = counts.sum(axis=0).astype(float)
    cum = np.cumsum(by_cat)[:-1] / by_cat.sum()
    theta = np.log(cum) - np.log1p(-cum)
    return np.r_[theta, np.zeros(counts.shape[0] - 1)]


def fit_cumulative_logit(counts: np.ndarray) -> CumulativeLogitFit:
    """Fit the model to a levels × categories table of answer counts (rows: factor levels, the first the
    reference; columns: the answer categories in order). Every level and every category needs an answer."""
    counts = np.asarray(counts)
    if counts.ndim != 2 or counts.shape[0] < 1 or counts.shape[1] < 2:
        raise StatsInputError(f"a cumulative logit fit needs a levels × categories table with at least 2 "
                              f"categories, got shape {counts.shape}")
    if np.any(counts < 0) or np.any(counts != np.round(counts)):
        raise StatsInputError("answer counts must be whole numbers ≥ 0")
    if np.any(counts.sum(axis=1) == 0) or np.any(counts.sum(axis=0) == 0):
        raise StatsInputError("every factor level and every answer category needs at least one answer")
    cells = _Cells(counts)
    params = _start(counts)
    llf = cells.llf(params)
    # the log-likelihood's rounding: a change smaller than this is no change
    noise = 1e-13 * max(1.0, abs(llf))
    converged, steps, moved = False, 0, 0.0
    for steps in range(1, MAX_STEPS + 1):  # noqa: B007 - steps is read after the loop
        grad, hess = cells.derivatives(params)
        if np.max(np.abs(grad)) < GRAD_TOL:
            converged = True
            break
        try:
            step = np.linalg.solve(-hess, grad)
        except np.linalg.LinAlgError:  # the information is singular on the way to infinity: least squares
            step = np.linalg.lstsq(-hess, grad, rcond=None)[0]
        # step halving: the log-likelihood is concave, so a short enough Newton step gains. Near the maximum the
        # full step's change is rounding noise either way; it is taken (a loss there is not a real loss).
        t = 1.0
        while (new := cells.llf(params + t * step)) < llf - noise:
            t /= 2
            if t < 1e-10:
                break
        if not new >= llf - noise:
            converged = True  # no step gains any more: at the maximum to rounding
            break
        gain, moved = new - llf, float(np.max(np.abs(t * step[cells.n_theta:]), initial=0.0))
        params, llf = params + t * step, new
        if gain <= noise and t == 1.0:  # the full Newton step changed nothing: at the maximum (or its supremum)
            converged = True
            break
    beta = params[cells.n_theta:]
    # at a finite maximum Newton's last steps shrink quadratically (to ~1e-6 and below); on the way to an
    # infinite one each step still adds ~1 to the diverging β while the likelihood's gain is at rounding level
    separated = bool(np.any(np.abs(beta) > SEPARATED_BETA) and moved > SEPARATED_STEP)
    cov = None
    if not separated:
        _, hess = cells.derivatives(params)
        try:
            cov = np.linalg.inv(-hess)
        except np.linalg.LinAlgError:
            cov = None
        if cov is not None and (not np.all(np.isfinite(cov)) or np.any(np.diag(cov) <= 0)):
            cov = None
    return CumulativeLogitFit(coef=beta.copy(), thresholds=params[:cells.n_theta].copy(), llf=float(llf), cov=cov,
                              steps=steps, converged=converged, separated=separated)


def count_table(values: np.ndarray, factor: np.ndarray, levels: list) -> tuple[np.ndarray, np.ndarray]:
    """The levels × categories counts of answers ``values`` by ``factor`` (rows in ``levels`` order; columns the
    sorted distinct answers), and those answers."""
    cats, code = np.unique(np.asarray(values), return_inverse=True)
    index = {lv: i for i, lv in enumerate(levels)}
    rows = np.array([index[v] for v in np.asarray(factor).tolist()], dtype=np.intp)
    counts = np.zeros((len(levels), len(cats)), dtype=np.int64)
    np.add.at(counts, (rows, code.ravel()), 1)
    return counts, cats
