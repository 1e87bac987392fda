"""Confidence intervals for the model-based tests (:mod:`studyctl.stats.models`).

* **Mixed model**: the fixed effects of the random-intercept model in treatment coding (the first level of each
  factor is the reference, as R's default ``contr.treatment``), each with its Wald interval
  (estimate ± z·SE). The variance components come from a REML fit (statsmodels MixedLM); the estimates and their
  covariance are the GLS ones given those components, σ²(X'V⁻¹X)⁻¹ — what R's
  ``confint(lmer(...), method = "Wald")`` gives (statsmodels' own ``bse_fe`` comes from the joint Hessian and
  differs in the third digit on unbalanced data).
* **Ordinal model**: the factor's log odds ratios (treatment coding) with Wald intervals from the fit's Hessian —
  R's ``confint.default(clm(...))`` (R's ``confint(clm)`` profiles the likelihood instead; not done here).
* **ART with an F test**: the interval of partial η² by inverting the noncentral F distribution in its
  noncentrality λ (Steiger 2004), η²p = λ / (λ + df1 + df2 + 1).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from studyctl.errors import StatsInputError

from .cumulative_logit import count_table, fit_cumulative_logit
from .model_design import (
    design_problem,
    factor_levels,
    factorial_terms,
    has_repeats,
    long_frame,
    no_variation,
    ordinal_problem,
)

NAN = math.nan


@dataclass(frozen=True)
class Coefficient:
    """One fixed effect: its estimate, standard error and Wald interval."""

    name: str
    estimate: float
    se: float
    ci_low: float
    ci_high: float


@dataclass(frozen=True)
class CoefficientTable:
    """The fixed effects of a fitted model with their intervals (``status`` not_computed with ``reason`` when the
    model could not be fitted)."""

    model: str
    coefficients: tuple[Coefficient, ...]
    ci_level: float
    method: str
    status: str = "ok"
    reason: str = ""

    def to_frame(self) -> pd.DataFrame:
        cols = ["name", "estimate", "se", "ci_low", "ci_high"]
        frame = pd.DataFrame([[getattr(c, k) for k in cols] for c in self.coefficients], columns=cols)
        return frame.assign(ci_level=self.ci_level, method=self.method)

    def coefficient(self, name: str) -> Coefficient:
        return next(c for c in self.coefficients if c.name == name)


def _check_confidence(confidence: float) -> float:
    if isinstance(confidence, bool) or not isinstance(confidence, (int, float)) or not 0 < confidence < 1:
        raise StatsInputError(f"confidence must be a number between 0 and 1, got {confidence!r}")
    return float(confidence)


def treatment_design(frame: pd.DataFrame, names: Sequence[str], levels: dict[str, list[str]]
                     ) -> tuple[np.ndarray, list[str]]:
    """Full-factorial design in treatment coding (intercept, then main effects, then interactions) and R-style
    column names (``group[expert]``, ``group[expert]:condition[linear]``)."""
    coded = {n: (np.column_stack([(frame[n].to_numpy() == lv).astype(float) for lv in levels[n][1:]]),
                 [f"{n}[{lv}]" for lv in levels[n][1:]]) for n in names}
    cols, labels = [np.ones((len(frame), 1))], ["(Intercept)"]
    for term in factorial_terms(names):
        block, lab = coded[term[0]]
        for n in term[1:]:
            other, olab = coded[n]
            block = np.einsum("ij,ik->ijk", block, other).reshape(len(frame), -1)
            lab = [f"{a}:{b}" for a in lab for b in olab]
        cols.append(block)
        labels += lab
    return np.hstack(cols), labels


def _gls(y: np.ndarray, x: np.ndarray, groups: np.ndarray, sigma2: float, tau2: float
         ) -> tuple[np.ndarray, np.ndarray]:
    """GLS estimate and covariance for V = σ²I + τ²·(1 per participant): per participant of size m,
    V⁻¹ = (I − τ²/(σ² + mτ²)·J)/σ² (Sherman–Morrison), so no N × N matrix is formed."""
    codes, idx = np.unique(groups, return_inverse=True)
    sizes = np.bincount(idx)
    shrink = tau2 / (sigma2 + sizes * tau2)  # per participant
    sx = np.zeros((len(codes), x.shape[1]))
    sy = np.zeros(len(codes))
    np.add.at(sx, idx, x)
    np.add.at(sy, idx, y)
    xtwx = (x.T @ x - (sx * shrink[:, None]).T @ sx) / sigma2
    xtwy = (x.T @ y - (sx * shrink[:, None]).T @ sy) / sigma2
    cov = np.linalg.inv(xtwx)
    return cov @ xtwy, cov


def mixed_coefficients(y: Sequence[float], factors: dict[str, Sequence], subject: Sequence, *,
                       levels: dict[str, Sequence[str]] | None = None, confidence: float = 0.95
                       ) -> CoefficientTable:
    """Fixed effects of the random-intercept model (REML variance components) with Wald intervals; see the
    module docstring. A design the model cannot fit comes back not computed with the reason."""
    from statsmodels.regression.mixed_linear_model import MixedLM

    level = _check_confidence(confidence)
    method = (f"Wald {level:.0%} intervals of the fixed effects (treatment coding), REML variance components "
              "(statsmodels MixedLM), GLS covariance")
    frame = long_frame(y, factors, subject)
    names = list(factors)
    lv = factor_levels(frame, names, levels)
    why = design_problem(frame, names, lv) or no_variation(frame["y"].to_numpy()) or (
        "" if has_repeats(frame) else "every participant has one value: no random intercept to estimate")
    if why:
        return CoefficientTable("mixed_model", (), level, method, "not_computed", why)
    x, labels = treatment_design(frame, names, lv)
    yv, groups = frame["y"].to_numpy(), frame["_subject"].to_numpy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = None
        for optimiser in (["lbfgs"], ["bfgs"], ["nm", "lbfgs"]):  # the next only when one fails
            try:
                fit = MixedLM(yv, x, groups=groups).fit(reml=True, method=optimiser)
            except (np.linalg.LinAlgError, ValueError):
                continue
            if fit.converged:
                break
        failed = fit is None or not np.isfinite(fit.llf)  # (evaluating llf warns on a degenerate fit)
    if failed:
        return CoefficientTable("mixed_model", (), level, method, "not_computed", "the REML fit failed")
    sigma2, tau2 = float(fit.scale), max(float(np.asarray(fit.cov_re)[0, 0]), 0.0)
    beta, cov = _gls(yv, x, groups, sigma2, tau2)
    return CoefficientTable("mixed_model", _wald(labels, beta, cov, level), level, method)


def _wald(labels: Sequence[str], beta: np.ndarray, cov: np.ndarray, level: float) -> tuple[Coefficient, ...]:
    from scipy import stats as _st  # lazy: importing scipy.stats costs about a second
    z = float(_st.norm.ppf(0.5 + level / 2))
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return tuple(Coefficient(name, float(b), float(s), float(b - z * s), float(b + z * s))
                 for name, b, s in zip(labels, beta, se, strict=True))


def ordinal_coefficients(y: Sequence[float], factor: Sequence, *, levels: Sequence[str] | None = None,
                         confidence: float = 0.95) -> CoefficientTable:
    """The factor's log odds ratios (treatment coding, first level the reference) in the cumulative logit model,
    with Wald intervals from the Hessian."""
    level = _check_confidence(confidence)
    method = f"Wald {level:.0%} intervals of the log odds ratios (cumulative logit, Newton-Raphson ML as R's clm)"
    frame = long_frame(y, {"factor": factor}, None)
    lv = factor_levels(frame, ["factor"], {"factor": list(levels or [])})["factor"]
    values = frame["y"].to_numpy()
    why = ordinal_problem(frame, {"factor": lv})
    if why:
        return CoefficientTable("ordinal", (), level, method, "not_computed", why)
    fit = fit_cumulative_logit(count_table(values, frame["factor"].to_numpy(), lv)[0])
    if fit.coef_cov is None:
        return CoefficientTable("ordinal", (), level, method, "not_computed",
                                "a level's answers are separated from another's (every answer at one end of the "
                                "scale?): its log odds ratio is infinite" if fit.separated else
                                "the Hessian is singular: the log odds ratios are not identified")
    return CoefficientTable("ordinal", _wald([f"factor[{v}]" for v in lv[1:]], fit.coef, fit.coef_cov, level),
                            level, method)


def partial_eta_squared_ci(f: float, df1: float, df2: float, confidence: float = 0.95) -> tuple[float, float]:
    """Interval of partial η² from an F statistic by inverting the noncentral F in λ (Steiger 2004):
    the λ where F is the upper and the lower (1 − level)/2 quantile, η²p = λ / (λ + df1 + df2 + 1).
    (NaN, NaN) when F or a df is not a finite positive number."""
    level = _check_confidence(confidence)
    if not (math.isfinite(f) and f >= 0 and math.isfinite(df1) and df1 > 0 and math.isfinite(df2) and df2 > 0):
        return NAN, NAN
    tail = (1 - level) / 2

    def ncp(target: float) -> float:
        """λ with P(F' ≤ f; λ) = target (0 when even λ = 0 leaves less than target below f)."""
        from scipy import optimize as _opt  # lazy, as scipy.stats: test collection and plan checks import this module
        from scipy import stats as _st  # lazy: importing scipy.stats costs about a second
        below = lambda lam: float(_st.ncf.cdf(f, df1, df2, lam)) if lam > 0 else float(_st.f.cdf(f, df1, df2))  # noqa: E731
        if below(0.0) <= target:
            return 0.0
        hi = max(10.0, f * df1 * 2)
        while below(hi) > target:
            hi *= 2
        return float(_opt.brentq(lambda lam: below(lam) - target, 0.0, hi, xtol=1e-12, rtol=1e-12))

    lo, hi = ncp(1 - tail), ncp(tail)
    return lo / (lo + df1 + df2 + 1), hi / (hi + df1 + df2 + 1)
