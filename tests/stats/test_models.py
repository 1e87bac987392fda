"""Model-based tests (ART ANOVA, linear mixed model, ordinal model) against R, and designs they cannot fit.

The reference values are computed by ``tests/reference/models/r_models.R`` (R 4.2, lme4, ordinal; its output
``r_models.json`` is committed with the R and package versions, so these tests never need R).
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from studyctl.stats.models import art_anova, mixed_model, ordinal_fit, ordinal_model

REF = Path(__file__).parents[1] / "reference" / "models"
R = json.loads((REF / "r_models.json").read_text())
LEVELS = {"group": ["novice", "expert"], "condition": ["none", "piecewise", "linear", "bio"]}


def rel(a: float, b: float) -> float:
    return abs(a - b) / max(abs(b), 1e-300)


def test_r_versions_are_recorded():
    assert R["R"].startswith("R version 4.") and R["lme4"] and R["ordinal"]


def test_art_between_subjects_matches_r_lm_on_aligned_ranks():
    d = pd.read_csv(REF / "art_between.csv")  # 2 × 3, unbalanced (4 to 8 per cell)
    res = art_anova(d["y"], {"a": d["a"], "b": d["b"]})
    for t in res.terms:
        r = R["art_between"][t.term]
        assert t.statistic_name == "F" and (t.df, t.df2) == (r["df1"], r["df2"])
        assert rel(t.statistic, r["F"]) < 1e-6 and rel(t.p, r["p"]) < 1e-6 and rel(t.effect_size, r["pes"]) < 1e-6
    # and R's own anova(lm) on the interaction's aligned ranks
    assert rel(res.term("a:b").statistic, R["art_between_interaction_anova_lm"]) < 1e-6


def test_art_mixed_design_matches_r_lmer_likelihood_ratio():
    d = pd.read_csv(REF / "mixed_unbalanced.csv")  # 7 vs 5 per group, 3 missing values
    res = art_anova(d["y"], {"group": d["group"], "condition": d["condition"]}, d["subject"], levels=LEVELS)
    for t in res.terms:
        r = R["art_mixed"][t.term]
        assert t.df == r["df"] and rel(t.statistic, r["chi2"]) < 1e-4 and rel(t.p, r["p"]) < 1e-4


def test_mixed_model_matches_lme4():
    d = pd.read_csv(REF / "mixed_unbalanced.csv")
    res = mixed_model(d["y"], {"group": d["group"], "condition": d["condition"]}, d["subject"], levels=LEVELS)
    assert res.n == len(d) == 45 and res.n_participants == 12
    for t in res.terms:
        r = R["mixed_model"][t.term]
        assert t.df == r["df"] and rel(t.statistic, r["chi2"]) < 1e-4 and rel(t.p, r["p"]) < 1e-4


def test_ordinal_model_matches_clm():
    d = pd.read_csv(REF / "likert.csv")
    levels = ["RT", "ES", "EG", "ESG"]
    fit, llf0 = ordinal_fit(d["y"].to_numpy(dtype=float), d["condition"].to_numpy(), levels)
    r = R["ordinal_model"]
    assert np.allclose(fit["coef"], r["coef"], rtol=1e-4) and np.allclose(fit["thresholds"], r["thresholds"],
                                                                          rtol=1e-4)
    assert rel(fit["llf"], r["llf"]) < 1e-6 and rel(llf0, r["llf0"]) < 1e-9
    (t,) = ordinal_model(d["y"], d["condition"], levels=levels, subject=d["subject"]).terms
    assert rel(t.statistic, r["chi2"]) < 1e-4 and rel(t.p, r["p"]) < 1e-4 and t.df == 3
    assert "independent" in t.reason  # repeated answers: said, not hidden


@pytest.mark.parametrize(
    ("rows", "reason"),
    [
        ([("g1", "A", 1.0), ("g1", "B", 2.0), ("g1", "A", 1.5), ("g1", "B", 2.5)], "one level"),
        ([("g1", "A", 1.0), ("g1", "B", 2.0), ("g2", "A", 1.5), ("g1", "A", 1.2), ("g1", "B", 2.2),
          ("g2", "A", 1.1)], "singular"),
        ([("g1", "A", 1.0), ("g1", "B", 2.0), ("g2", "A", 1.5), ("g2", "B", 2.5)], "no replication"),
    ],
)
def test_designs_that_cannot_be_fitted_are_flagged(rows, reason):
    g, c, y = zip(*rows, strict=True)
    for fn in (art_anova, mixed_model):
        res = fn(list(y), {"group": list(g), "condition": list(c)}, [f"P{i // 2}" for i in range(len(y))])
        assert {t.status for t in res.terms} == {"not_computed"}, fn.__name__
        assert all(reason in t.reason for t in res.terms)


def test_ordinal_refuses_averaged_answers_and_constant_answers():
    (t,) = ordinal_model([1, 2.5, 3, 4], ["A", "A", "B", "B"]).terms
    assert t.status == "not_computed" and "whole numbers" in t.reason
    (t,) = ordinal_model([3, 3, 3, 3], ["A", "A", "B", "B"]).terms
    assert t.status == "not_computed" and "same" in t.reason


# --- the closed-form ML fit of balanced random-intercept designs (what a power analysis fits thousands of) ------


def _balanced(rng: np.random.Generator, n: int, sd_subject: float, *, drop: int = 0):
    """A 2 (group, between) × 4 (condition, within) design, one value per participant × condition."""
    from studyctl.stats import model_design as md

    group = np.repeat(np.where(np.arange(n) < n // 3, "expert", "novice"), 4)
    cond = np.tile(LEVELS["condition"], n)
    subject = np.repeat([f"P{i:02d}" for i in range(n)], 4)
    y = rng.normal(size=4 * n) + np.repeat(rng.normal(size=n) * sd_subject, 4) + (cond == "linear") * 0.7
    y[:drop] = np.nan
    frame = md.long_frame(y, {"group": group, "condition": cond}, subject)
    names = ["group", "condition"]
    x, assign = md.design(frame, names, md.factor_levels(frame, names, LEVELS))
    return frame, x, assign


def _dense_ml_llf(y: np.ndarray, x: np.ndarray, subject: np.ndarray) -> float:
    """The ML log-likelihood by brute force: GLS with the dense V = σ²(I + γZZ'), σ² profiled, γ ≥ 0 searched."""
    from scipy import optimize

    _, idx = np.unique(subject, return_inverse=True)
    z = (idx[:, None] == np.arange(idx.max() + 1)).astype(float)
    n = len(y)

    def neg(gamma: float) -> float:
        v = np.eye(n) + gamma * z @ z.T
        vi = np.linalg.inv(v)
        beta = np.linalg.solve(x.T @ vi @ x, x.T @ vi @ y)
        r = y - x @ beta
        return 0.5 * (n * np.log(2 * np.pi * (r @ vi @ r) / n) + np.linalg.slogdet(v)[1] + n)

    best = optimize.minimize_scalar(neg, bounds=(0.0, 50.0), method="bounded", options={"xatol": 1e-11})
    return -min(best.fun, neg(0.0))


@pytest.mark.parametrize(("n", "sd_subject", "seed"), [(6, 0.0, 1), (9, 0.1, 2), (12, 1.0, 3), (20, 3.0, 4),
                                                       (5, 0.0, 5)])
def test_balanced_closed_form_is_the_exact_ml_maximum(n, sd_subject, seed):
    from studyctl.stats.models import _balanced_llf

    frame, x, assign = _balanced(np.random.default_rng(seed), n, sd_subject)
    y, subject = frame["y"].to_numpy(), frame["_subject"].to_numpy()
    for t in (None, 0, 1, 2):  # the full model and each model without one term (the LR tests' fits)
        cols = [j for j, a in enumerate(assign) if a != t]
        closed = _balanced_llf(y, x[:, cols], subject)
        assert closed is not None
        assert abs(closed - _dense_ml_llf(y, x[:, cols], subject)) < 1e-7


def test_balanced_closed_form_agrees_with_statsmodels_where_the_optimiser_converges():
    from studyctl.stats.models import _balanced_llf, _mixed_llf_iterative

    # a clear participant effect keeps the optimum inside (τ² > 0), where MixedLM's climb is reliable; at the
    # τ² = 0 boundary MixedLM stops short (found up to 2.6 log-likelihood units below the true maximum above)
    frame, x, _ = _balanced(np.random.default_rng(7), 14, 3.0)
    y, subject = frame["y"].to_numpy(), frame["_subject"].to_numpy()
    assert abs(_balanced_llf(y, x, subject) - _mixed_llf_iterative(y, x, subject)) < 1e-5


def test_unbalanced_designs_go_to_the_iterative_fit():
    from studyctl.stats.models import _balanced_llf

    frame, x, _ = _balanced(np.random.default_rng(8), 8, 1.0, drop=1)  # one participant has 3 of 4 values
    assert _balanced_llf(frame["y"].to_numpy(), x, frame["_subject"].to_numpy()) is None
    frame, x, _ = _balanced(np.random.default_rng(8), 8, 1.0)
    # a column that varies within participants but whose participant means leave col(X): no closed form
    x2 = np.column_stack([x, np.arange(len(x)) % 3])
    assert _balanced_llf(frame["y"].to_numpy(), x2, frame["_subject"].to_numpy()) is None


def test_mixed_model_on_a_balanced_design_gives_the_exact_likelihood_ratio():
    frame, x, assign = _balanced(np.random.default_rng(9), 10, 0.5)
    res = mixed_model(frame["y"], {"group": frame["group"], "condition": frame["condition"]}, frame["_subject"],
                      levels=LEVELS)
    y, subject = frame["y"].to_numpy(), frame["_subject"].to_numpy()
    full = _dense_ml_llf(y, x, subject)
    for t, term in enumerate(res.terms):
        reduced = _dense_ml_llf(y, x[:, [j for j, a in enumerate(assign) if a != t]], subject)
        assert term.status == "ok" and abs(term.statistic - 2 * (full - reduced)) < 1e-6


# ------------------------------------------------------------------------------------------ intervals


def test_mixed_model_coefficient_intervals_match_lme4_wald():
    from studyctl.stats.model_intervals import mixed_coefficients

    d = pd.read_csv(REF / "mixed_unbalanced.csv")  # unbalanced: 7 vs 5 per group, 3 missing within-cells
    table = mixed_coefficients(d["y"], {"group": d["group"], "condition": d["condition"]}, d["subject"],
                               levels=LEVELS)
    r = R["mixed_coefficients"]
    frame = table.to_frame()
    assert table.status == "ok" and [n.replace("[", "").replace("]", "") for n in frame["name"]] == r["names"]
    for col, key in (("estimate", "estimate"), ("se", "se"), ("ci_low", "low"), ("ci_high", "high")):
        got, want = frame[col].to_numpy(), np.asarray(r[key])
        # relative to the interval's half-width: bounds near zero make a plain relative difference meaningless
        assert np.max(np.abs(got - want) / np.asarray(r["se"])) < 1e-4, (col, got - want)


def test_ordinal_coefficient_intervals_match_clm_wald():
    from studyctl.stats.model_intervals import ordinal_coefficients

    d = pd.read_csv(REF / "likert.csv")
    table = ordinal_coefficients(d["y"], d["condition"], levels=["RT", "ES", "EG", "ESG"])
    frame = table.to_frame()
    assert list(frame["name"]) == ["factor[ES]", "factor[EG]", "factor[ESG]"]
    assert np.allclose(frame["ci_low"], R["ordinal_wald"]["low"], rtol=1e-4)
    assert np.allclose(frame["ci_high"], R["ordinal_wald"]["high"], rtol=1e-4)
    assert np.allclose(frame["estimate"], R["ordinal_model"]["coef"], rtol=1e-4)


def test_art_partial_eta_squared_interval_matches_noncentral_f_inversion_in_r():
    from studyctl.stats.model_intervals import partial_eta_squared_ci

    d = pd.read_csv(REF / "art_between.csv")
    res = art_anova(d["y"], {"a": d["a"], "b": d["b"]})
    for t in res.terms:
        lo, hi = R["art_between_pes_ci"][t.term]
        assert (t.effect_ci_low, t.effect_ci_high) == partial_eta_squared_ci(t.statistic, t.df, t.df2)
        assert abs(t.effect_ci_low - lo) < 1e-6 and abs(t.effect_ci_high - hi) < 1e-6 * max(hi, 1)
        assert t.effect_ci_low <= t.effect_size <= t.effect_ci_high


def test_intervals_of_designs_that_cannot_be_fitted_are_flagged():
    from studyctl.stats.model_intervals import mixed_coefficients, ordinal_coefficients, partial_eta_squared_ci

    table = mixed_coefficients([1.0, 2.0, 1.5, 2.5], {"condition": ["A", "A", "A", "A"]}, ["P0", "P0", "P1", "P1"])
    assert table.status == "not_computed" and "one level" in table.reason and table.to_frame().empty
    table = ordinal_coefficients([1, 2.5, 3, 4], ["A", "A", "B", "B"])
    assert table.status == "not_computed" and "whole numbers" in table.reason
    assert all(np.isnan(partial_eta_squared_ci(float("nan"), 1, 10)))
    with pytest.raises(ValueError, match="confidence"):
        partial_eta_squared_ci(3.0, 1, 10, confidence=1.5)


@pytest.mark.parametrize("repeated", [True, False])
def test_a_response_that_does_not_vary_is_flagged_not_a_number(repeated):
    # (was: ART χ² = 13.2, p = 0.0003 for the group term of a constant response; F = −0.6 between subjects)
    subject = [f"P{i}" for i in range(8) for _ in range(3)] if repeated else None
    factors = {"group": ["n" if i < 12 else "e" for i in range(24)], "condition": ["A", "B", "C"] * 8}
    fns = (art_anova, mixed_model) if repeated else (art_anova,)
    for fn in fns:
        res = fn([5.0] * 24, factors, subject)
        assert {t.status for t in res.terms} == {"not_computed"}, fn.__name__
        assert all("does not vary" in t.reason and np.isnan(t.p) for t in res.terms)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_margin_means_are_pandas_groupby_means_bit_for_bit(seed):
    """The aligned rank transform's margins are the groupby means pandas gives, to the last bit: an aligned
    value that ties another one must still tie (discrete metrics tie often), or the ranks, and the p-value,
    change. Values of very different size make plain summation and pandas' compensated one differ."""
    from studyctl.stats.models import _group_codes, _margin_mean, aligned_responses

    rng = np.random.default_rng(seed)
    n = 400
    frame = pd.DataFrame({
        "y": np.where(rng.random(n) < 0.5, rng.choice([0.0, 1 / 3, 2 / 3, 1.0], n), rng.normal(0, 1e8, n)
                      + rng.normal(0, 1e-3, n)),
        "a": rng.choice(["novice", "expert"], n),
        "b": rng.choice(["no_feedback", "piecewise", "linear", "bio_inspired"], n),
    })
    codes = _group_codes(frame, ["a", "b"])
    for factors in (["a"], ["b"], ["a", "b"]):
        got = _margin_mean(frame["y"].to_numpy(), codes, factors)
        want = frame.groupby(factors)["y"].transform("mean").to_numpy()
        assert np.array_equal(got, want)
    # the comparison can fail: plain (uncompensated) sums give other means for these values
    _, idx = np.unique(codes["a"] * 4 + codes["b"], return_inverse=True)
    plain = (np.bincount(idx, weights=frame["y"].to_numpy()) / np.bincount(idx))[idx]
    assert not np.array_equal(plain, frame.groupby(["a", "b"])["y"].transform("mean").to_numpy())
    for term in (("a",), ("b",), ("a", "b")):
        y = frame["y"].to_numpy()
        cell = frame.groupby(["a", "b"])["y"].transform("mean").to_numpy()
        effect = np.zeros(n)
        for k in range(len(term) + 1):
            for sub in itertools.combinations(term, k):
                means = frame.groupby(list(sub))["y"].transform("mean").to_numpy() if sub else np.full(n, y.mean())
                effect += (-1) ** (len(term) - k) * means
        assert np.array_equal(aligned_responses(frame, ["a", "b"], term), (y - cell) + effect)
