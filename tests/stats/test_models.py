"""Model-based tests (ART ANOVA, linear mixed model, ordinal model) against R, and designs they cannot fit.

The reference values are computed by ``tests/reference/models/r_models.R`` (R 4.2, lme4, ordinal; its output
``r_models.json`` is committed with the R and package versions, so these tests never need R).
"""

from __future__ import annotations

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
