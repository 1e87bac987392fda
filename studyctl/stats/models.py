"""Model-based tests reviewers ask for: the aligned rank transform ANOVA, a linear mixed model with a
participant random intercept, and a cumulative link (ordinal logistic) model for Likert answers.

Every function takes long-form arrays (one value per observation, its factor levels, its participant) and
returns a frozen :class:`ModelResult` with one :class:`ModelTerm` per tested term. A term that cannot be
estimated (a factor with one level, an empty design cell that makes the design singular, no replication)
is returned with ``status = "not_computed"`` and the reason; nothing raises for a design problem.

How each term is tested (stated in every term's ``method``):

* **OLS terms** (no participant seen twice): type III F — the residual sum of squares of the full
  factorial model (sum-to-zero contrasts) against the model without the term's columns.
* **Mixed terms** (a participant in more than one row): likelihood-ratio χ² between maximum-likelihood fits
  of the random-intercept model with and without the term's columns (statsmodels MixedLM; the same as R
  ``anova(lmer(..., REML = FALSE), ...)``). Satterthwaite / Kenward-Roger F-tests are not implemented.
  When every participant has one row per within-level (a balanced design) the ML fit has a closed form
  (:func:`_balanced_llf`): exact, and on the τ² = 0 boundary higher than where MixedLM's optimiser stops.
* **ART** (Wobbrock et al. 2011): for each term the response is aligned (residual from the full-factorial
  cell means plus the term's estimated effect from marginal means of the observations), ranked with
  average ties, and only that term is read from the model fitted to those ranks (OLS or mixed, as above).
* **Ordinal**: proportional-odds cumulative logit model (our Newton-Raphson fit with analytic derivatives,
  :mod:`studyctl.stats.cumulative_logit`; checked against R's clm and statsmodels), likelihood-ratio χ²
  against the thresholds-only model. Without a participant random effect (R's clmm is not
  implemented); repeated answers of one person are treated as independent (stated).
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from studyctl.errors import StatsInputError

from .cumulative_logit import count_table, fit_cumulative_logit, null_llf
from .model_design import (
    design,
    design_problem,
    factor_levels,
    factorial_terms,
    has_repeats,
    long_frame,
    no_variation,
    ordinal_problem,
    term_name,
)
from .model_intervals import partial_eta_squared_ci
from .summary import TestSummary

NAN = math.nan


@dataclass(frozen=True)
class ModelTerm:
    """The test of one model term (a factor or an interaction)."""

    term: str
    statistic_name: str  # "F" or "chi2 (LR)"
    statistic: float
    df: float
    df2: float
    p: float
    effect_size_name: str = ""
    effect_size: float = NAN
    method: str = ""
    status: str = "ok"
    reason: str = ""
    # 95 % interval of the effect size where one is known (ART's F rows: noncentral F inversion)
    effect_ci_low: float = NAN
    effect_ci_high: float = NAN

    def summary(self) -> TestSummary:
        return TestSummary(self.statistic_name, self.statistic, p=self.p, df=self.df, df2=self.df2,
                           effect_size_name=self.effect_size_name, effect_size=self.effect_size,
                           method=self.method, warnings=(self.reason,) if self.reason else ())


@dataclass(frozen=True)
class ModelResult:
    """A model-based test: one :class:`ModelTerm` per term, in model order."""

    model: str
    terms: tuple[ModelTerm, ...]
    n: int
    n_participants: int
    warnings: tuple[str, ...] = ()

    def to_frame(self) -> pd.DataFrame:
        cols = ["term", "statistic_name", "statistic", "df", "df2", "p", "effect_size_name", "effect_size",
                "effect_ci_low", "effect_ci_high", "method", "status", "reason"]
        return pd.DataFrame([[getattr(t, c) for c in cols] for t in self.terms], columns=cols)

    def term(self, name: str) -> ModelTerm:
        return next(t for t in self.terms if t.term == name)


# --------------------------------------------------------------------------------------- fitting


def _ols_f(y: np.ndarray, x: np.ndarray, assign: list[int], t: int) -> tuple[float, float, float, float, float]:
    """Type III F of term ``t``: (F, df1, df2, p, partial η²)."""
    def rss(m: np.ndarray) -> tuple[float, int]:
        beta, _, rank, _ = np.linalg.lstsq(m, y, rcond=None)
        r = y - m @ beta
        return float(r @ r), int(rank)

    rss_f, rank_f = rss(x)
    keep = [j for j, a in enumerate(assign) if a != t]
    rss_r, rank_r = rss(x[:, keep])
    df1, df2 = rank_f - rank_r, len(y) - rank_f
    ss = max(rss_r - rss_f, 0.0)  # rounding can leave a tiny negative difference
    if rss_f <= 1e-12 * float(((y - y.mean()) ** 2).sum()):
        raise np.linalg.LinAlgError("no residual variance: the model fits every observation exactly")
    f = (ss / df1) / (rss_f / df2)
    from scipy import stats as _st  # lazy: importing scipy.stats costs about a second

    p = float(_st.f.sf(f, df1, df2))
    return f, float(df1), float(df2), p, ss / (ss + rss_f) if ss + rss_f > 0 else NAN


def _balanced_llf(y: np.ndarray, x: np.ndarray, groups: np.ndarray) -> float | None:
    """The ML log-likelihood of the random-intercept model in closed form, or None when the design is not one
    where that form holds.

    It holds when every participant has the same number m ≥ 2 of rows and the participant-mean of every column
    of X lies in X's column space (e.g. a full factorial with sum-to-zero contrasts where every participant has
    one row per within-level: within columns average to 0 per participant, between columns are constant). Then
    V = σ²I + τ²ZZ' leaves col(X) invariant, so GLS = OLS for every (σ², τ²) (Zyskind 1967), and the OLS
    residual splits into a between-participant part (participant means, variance λ1 = σ² + mτ², n dims) and a
    within part (λ0 = σ², N − n dims), each with its own closed-form ML variance; τ² ≥ 0 puts λ1 ≥ λ0, and when
    the unconstrained optimum breaks that the optimum is on λ1 = λ0 (the pooled variance). The same maximum
    statsmodels' MixedLM climbs to iteratively, in a few small matrix products (a replicate of a power
    analysis fits dozens of these).
    """
    codes, idx = np.unique(groups, return_inverse=True)
    n, big_n = len(codes), len(y)
    sizes = np.bincount(idx, minlength=n)
    m = int(sizes[0])
    if n < 2 or m < 2 or np.any(sizes != m):
        return None

    def means(a: np.ndarray) -> np.ndarray:  # each row's participant mean
        sums = np.zeros((n, *a.shape[1:]))
        np.add.at(sums, idx, a)
        return sums[idx] / m

    px = means(x)
    beta, *_ = np.linalg.lstsq(x, np.column_stack([y, px]), rcond=None)
    leak = px - x @ beta[:, 1:]
    if not np.all(np.abs(leak) <= 1e-9 * max(1.0, float(np.abs(x).max()))):
        return None
    r = y - x @ beta[:, 0]
    rb = means(r)
    rss_b, rss_w = float(rb @ rb), float((r - rb) @ (r - rb))
    total = rss_b + rss_w
    if not total > 0 or rss_w <= 1e-12 * total:
        return None  # a perfect within-participant fit: the likelihood has no maximum (left to the optimiser)
    lam0, lam1 = rss_w / (big_n - n), rss_b / n
    if lam1 < lam0:
        lam0 = lam1 = total / big_n
    return float(-0.5 * (big_n * math.log(2 * math.pi) + (big_n - n) * math.log(lam0) + n * math.log(lam1)
                         + rss_w / lam0 + rss_b / lam1))


def _mixed_llf(y: np.ndarray, x: np.ndarray, groups: np.ndarray) -> float:
    """Maximum-likelihood log-likelihood of y = Xβ + u_subject + e: in closed form for balanced designs
    (:func:`_balanced_llf`), else by statsmodels MixedLM (ML)."""
    closed = _balanced_llf(y, x, groups)
    if closed is not None:
        return closed
    return _mixed_llf_iterative(y, x, groups)


def _mixed_llf_iterative(y: np.ndarray, x: np.ndarray, groups: np.ndarray) -> float:
    """Maximum-likelihood log-likelihood of y = Xβ + u_subject + e (statsmodels MixedLM, ML)."""
    from statsmodels.regression.mixed_linear_model import MixedLM
    from statsmodels.tools.sm_exceptions import ConvergenceWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        warnings.simplefilter("ignore", RuntimeWarning)
        warnings.simplefilter("ignore", UserWarning)
        model = MixedLM(y, x, groups=groups)
        best = None
        for method in (["lbfgs"], ["bfgs"], ["nm", "lbfgs"]):  # the next optimiser only when one fails
            try:
                fit = model.fit(reml=False, method=method)
            except (np.linalg.LinAlgError, ValueError):
                continue
            if best is None or fit.llf > best.llf:
                best = fit
            if fit.converged and np.isfinite(fit.llf):
                break
    if best is None:
        raise np.linalg.LinAlgError("the mixed model could not be fitted")
    return float(best.llf)


def _term_df(x: np.ndarray, assign: list[int], t: int) -> int:
    """Degrees of freedom of term ``t``: rank of X minus rank of X without the term's columns."""
    keep = [j for j, a in enumerate(assign) if a != t]
    return int(np.linalg.matrix_rank(x) - np.linalg.matrix_rank(x[:, keep]))


def _mixed_lr(y: np.ndarray, x: np.ndarray, assign: list[int], t: int, groups: np.ndarray,
              full_llf: float | None = None, df: int | None = None) -> tuple[float, float, float, float]:
    """(χ², df, p, full llf) of the likelihood-ratio test of term ``t`` (ML fits with and without it);
    ``df``: the term's :func:`_term_df` when the caller tests it on several responses of one design."""
    from scipy import stats as _st  # lazy: importing scipy.stats costs about a second
    keep = [j for j, a in enumerate(assign) if a != t]
    llf_f = _mixed_llf(y, x, groups) if full_llf is None else full_llf
    llf_r = _mixed_llf(y, x[:, keep], groups)
    df = _term_df(x, assign, t) if df is None else df
    chi2 = max(2.0 * (llf_f - llf_r), 0.0)
    return chi2, float(df), float(_st.chi2.sf(chi2, df)), llf_f


# ----------------------------------------------------------------------------------------- tests


def _not_computed(model: str, names: Sequence[str], frame: pd.DataFrame, reason: str) -> ModelResult:
    terms = tuple(ModelTerm(term_name(t), "", NAN, NAN, NAN, NAN, status="not_computed", reason=reason)
                  for t in factorial_terms(names))
    return ModelResult(model, terms, len(frame), int(frame["_subject"].nunique()) if len(frame) else 0)


def mixed_model(y: Sequence[float], factors: dict[str, Sequence], subject: Sequence, *,
                levels: dict[str, Sequence[str]] | None = None) -> ModelResult:
    """Linear mixed model, full factorial of ``factors``, random intercept per ``subject``; each term by a
    likelihood-ratio test of ML fits (see the module docstring)."""
    frame = long_frame(y, factors, subject)
    names = list(factors)
    lv = factor_levels(frame, names, levels)
    why = design_problem(frame, names, lv) or no_variation(frame["y"].to_numpy())
    if not why and not has_repeats(frame):
        why = "every participant has one value: no random intercept to estimate (use a between-subject test)"
    if why:
        return _not_computed("mixed_model", names, frame, why)
    x, assign = design(frame, names, lv)
    yv, groups = frame["y"].to_numpy(), frame["_subject"].to_numpy()
    out, llf = [], None
    method = ("linear mixed model, random intercept per participant (ML fits, statsmodels MixedLM); "
              "likelihood-ratio χ² of the term (sum-to-zero contrasts)")
    for t, term in enumerate(factorial_terms(names)):
        try:
            chi2, df, p, llf = _mixed_lr(yv, x, assign, t, groups, llf)
        except np.linalg.LinAlgError as exc:
            out.append(ModelTerm(term_name(term), "", NAN, NAN, NAN, NAN, status="not_computed", reason=str(exc)))
            continue
        if not math.isfinite(chi2):
            out.append(ModelTerm(term_name(term), "", NAN, NAN, NAN, NAN, status="not_computed",
                                 reason="the likelihood could not be evaluated at the fitted values"))
            continue
        out.append(ModelTerm(term_name(term), "chi2 (LR)", chi2, df, NAN, p, method=method))
    return ModelResult("mixed_model", tuple(out), len(frame), int(frame["_subject"].nunique()))


def _group_codes(frame: pd.DataFrame, names: Sequence[str]) -> dict[str, np.ndarray]:
    """Each factor's values as integer codes (the groups of every margin are then integer combinations)."""
    return {n: np.unique(frame[n].to_numpy(dtype=object), return_inverse=True)[1].ravel() for n in names}


def _margin_mean(y: np.ndarray, codes: dict[str, np.ndarray], factors: Sequence[str]) -> np.ndarray:
    """Each observation's mean of y over the observations sharing its levels of ``factors`` (none: the grand
    mean), bit for bit what ``groupby(factors)["y"].transform("mean")`` gives: pandas sums each group in row
    order with Kahan compensation, and the aligned ranks depend on the last bit (an aligned value that ties
    another one exactly must still tie: discrete metrics such as an accuracy tie often). A plain loop over a
    few hundred rows costs far less than pandas' groupby machinery (a power analysis aligns thousands)."""
    if not factors:
        return np.full(len(y), y.mean())
    key = np.zeros(len(y), dtype=np.int64)
    for n in factors:
        key = key * (int(codes[n].max()) + 1) + codes[n]
    _, idx = np.unique(key, return_inverse=True)
    idx = idx.ravel()
    k = int(idx.max()) + 1 if len(idx) else 0
    sums, comp, count = [0.0] * k, [0.0] * k, [0] * k
    for g, v in zip(idx.tolist(), y.tolist(), strict=True):
        count[g] += 1
        d = v - comp[g]
        t = sums[g] + d
        c = t - sums[g] - d
        comp[g] = 0.0 if c != c else c  # an infinite value makes the compensation NaN (pandas GH#50367)
        sums[g] = t
    means = np.array([a / b for a, b in zip(sums, count, strict=True)])
    return means[idx]


def aligned_responses(frame: pd.DataFrame, names: Sequence[str], term: tuple[str, ...],
                      codes: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """Wobbrock et al. (2011) alignment for ``term``: residual from the full-factorial cell means plus the
    term's estimated effect (inclusion–exclusion of marginal means of the observations). ``codes``: the
    factors' :func:`_group_codes` when the caller aligns several terms of one frame."""
    y = frame["y"].to_numpy(dtype=float)
    codes = _group_codes(frame, names) if codes is None else codes
    cell_mean = _margin_mean(y, codes, list(names))
    effect = np.zeros(len(frame))
    for k in range(len(term) + 1):
        for sub in itertools.combinations(term, k):
            sign = (-1) ** (len(term) - k)
            effect += sign * _margin_mean(y, codes, sub)
    return (y - cell_mean) + effect


def art_anova(y: Sequence[float], factors: dict[str, Sequence], subject: Sequence | None = None, *,
              levels: dict[str, Sequence[str]] | None = None) -> ModelResult:
    """Aligned rank transform ANOVA of the full factorial of ``factors`` (two or more)."""
    from scipy import stats as _st  # lazy: importing scipy.stats costs about a second
    frame = long_frame(y, factors, subject)
    names = list(factors)
    if len(names) < 2:
        raise StatsInputError("the aligned rank transform needs at least two factors (use a rank test for one)")
    lv = factor_levels(frame, names, levels)
    why = design_problem(frame, names, lv) or no_variation(frame["y"].to_numpy())
    if why:
        return _not_computed("art_anova", names, frame, why)
    x, assign = design(frame, names, lv)
    repeated = has_repeats(frame)
    groups = frame["_subject"].to_numpy()
    codes = _group_codes(frame, names)
    out = []
    for t, term in enumerate(factorial_terms(names)):
        ranks = _st.rankdata(aligned_responses(frame, names, term, codes))
        flat = no_variation(ranks, "every aligned rank")
        if flat:  # the term's aligned responses are all tied: a fit would report rounding noise as an effect
            out.append(ModelTerm(term_name(term), "", NAN, NAN, NAN, NAN, status="not_computed", reason=flat))
            continue
        try:
            if repeated:
                chi2, df, p, _ = _mixed_lr(ranks, x, assign, t, groups)
                out.append(ModelTerm(term_name(term), "chi2 (LR)", chi2, df, NAN, p, method=(
                    "aligned rank transform (Wobbrock et al. 2011); ranks in a random-intercept model per "
                    "participant, likelihood-ratio χ² of ML fits")))
            else:
                f, df1, df2, p, pes = _ols_f(ranks, x, assign, t)
                lo, hi = partial_eta_squared_ci(f, df1, df2)
                out.append(ModelTerm(term_name(term), "F", f, df1, df2, p, "partial_eta_squared", pes, method=(
                    "aligned rank transform (Wobbrock et al. 2011); type III F on the aligned ranks; 95% interval "
                    "of partial η² by noncentral F inversion"), effect_ci_low=lo, effect_ci_high=hi))
        except np.linalg.LinAlgError as exc:
            out.append(ModelTerm(term_name(term), "", NAN, NAN, NAN, NAN, status="not_computed", reason=str(exc)))
    return ModelResult("art_anova", tuple(out), len(frame), int(frame["_subject"].nunique()))


def ordinal_model(y: Sequence[float], factor: Sequence, *, levels: Sequence[str] | None = None,
                  subject: Sequence | None = None) -> ModelResult:
    """Proportional-odds cumulative logit model of ordinal answers ``y`` on one factor; the factor's
    likelihood-ratio χ² against the thresholds-only model. Answers must be whole numbers."""
    from scipy import stats as _st  # lazy: importing scipy.stats costs about a second
    frame = long_frame(y, {"factor": factor}, subject)
    lv = factor_levels(frame, ["factor"], {"factor": levels or []})
    why = ordinal_problem(frame, lv)
    values = frame["y"].to_numpy()
    if why:
        return ModelResult("ordinal", (ModelTerm("factor", "", NAN, NAN, NAN, NAN, status="not_computed",
                                                 reason=why),), len(frame), int(frame["_subject"].nunique()))
    fit, llf0 = ordinal_fit(values, frame["factor"].to_numpy(), lv["factor"])
    chi2 = max(2.0 * (fit["llf"] - llf0), 0.0)
    df = float(len(lv["factor"]) - 1)
    n_obs = len(values)
    # Nagelkerke's pseudo-R² as the effect size (Cox-Snell scaled to a maximum of 1).
    cs = 1 - math.exp(-chi2 / n_obs)
    nag = cs / (1 - math.exp(2 * llf0 / n_obs))
    notes = []
    if has_repeats(frame):
        notes.append("repeated answers of one participant treated as independent (no participant random effect)")
    if fit["separated"]:
        notes.append("a level's answers are separated from another's (its coefficient is infinite); the χ² uses the "
                     "likelihood's supremum")
    warn = "; ".join(notes)
    term = ModelTerm("factor", "chi2 (LR)", chi2, df, NAN, float(_st.chi2.sf(chi2, df)), "nagelkerke_r2", nag,
                     method="cumulative logit (proportional odds) model, maximum likelihood by Newton-Raphson (as "
                     "R's ordinal::clm); likelihood-ratio χ² against the thresholds-only model", reason=warn)
    return ModelResult("ordinal", (term,), len(frame), int(frame["_subject"].nunique()))


def ordinal_fit(values: np.ndarray, factor: np.ndarray, levels: list[str]) -> tuple[dict, float]:
    """The fitted cumulative logit model (treatment coding, first level as reference): coefficients,
    thresholds (R's clm parameterisation: logit P(Y ≤ j) = θ_j − xβ), log-likelihood, whether a level is
    separated (its coefficient infinite; the log-likelihood is then the supremum); and the null llf.
    Newton-Raphson on the levels × answers table (:mod:`studyctl.stats.cumulative_logit`)."""
    counts, _ = count_table(values, factor, levels)
    fit = fit_cumulative_logit(counts)
    return ({"coef": fit.coef, "thresholds": fit.thresholds, "llf": fit.llf, "separated": fit.separated},
            null_llf(counts.sum(axis=0)))
