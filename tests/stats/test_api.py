"""Public API shape and bad-input errors."""

from __future__ import annotations

import dataclasses
import math

import pytest

from studyctl import stats
from studyctl.errors import StatsInputError

PUBLIC = ["rank_sum", "signed_rank", "signed_rank_critical", "kruskal_wallis", "dunn", "anova_oneway", "tukey_hsd",
          "wilson_interval", "newcombe_interval", "friedman", "rm_anova"]


def test_all_exports_public_api():
    for name in PUBLIC:
        assert name in stats.__all__ and callable(getattr(stats, name))
    assert sorted(stats.__all__) == stats.__all__


def test_results_are_frozen_with_fixed_frames():
    results = [
        stats.rank_sum([1, 2, 3], [4, 5]), stats.signed_rank([1, -2, 3, 4]), stats.kruskal_wallis([1, 2], [3, 4]),
        stats.anova_oneway([1, 2], [3, 5]), stats.wilson_interval(3, 10), stats.newcombe_interval(3, 10, 5, 10),
        stats.friedman([1, 2, 3], [2, 3, 4]), stats.rm_anova([1, 2, 3], [2, 4, 3]),
    ]
    for r in results:
        with pytest.raises(dataclasses.FrozenInstanceError):
            r.pvalue = 0.0 if hasattr(r, "pvalue") else None  # type: ignore[misc]
        frame = r.to_frame()
        assert list(frame.columns) == [f.name for f in dataclasses.fields(r)] and len(frame) == 1
    t = stats.tukey_hsd({"a": [1, 2, 3], "b": [3, 4, 6], "c": [7, 8, 8]})
    assert list(t.to_frame().columns) == ["group1", "group2", "diff", "lower", "upper", "p_adj"]
    assert list(t.to_frame().group1) == ["a", "a", "b"] and t.diff[0] == pytest.approx(7 / 3)
    d = stats.dunn([1, 2, 3], [3, 4, 6], [7, 8, 8], names=["x", "y", "z"])
    assert list(d.to_frame().columns) == ["group1", "group2", "mean_rank_diff", "z", "pvalue", "p_adj"]


@pytest.mark.parametrize(
    "call,needle",
    [
        (lambda: stats.rank_sum([], [1, 2]), "x is empty"),
        (lambda: stats.rank_sum([1, "a"], [1, 2]), "x must contain only numbers"),
        (lambda: stats.rank_sum([1], [2], alternative="bigger"), "alternative must be one of"),
        (lambda: stats.rank_sum([1], [2], method="fast"), "method must be one of"),
        (lambda: stats.signed_rank([1, 2], [1, 2, 3]), "same length"),
        (lambda: stats.signed_rank([1, 2], zero_method="drop"), "zero_method"),
        (lambda: stats.kruskal_wallis([1, 2, 3]), "at least 2 groups"),
        (lambda: stats.anova_oneway([1, 2]), "at least 2 groups"),
        (lambda: stats.tukey_hsd([1, 2], [3, 4], confidence=1.5), "confidence must be in the open interval (0, 1)"),
        (lambda: stats.wilson_interval(11, 10), "successes must be between 0 and n=10"),
        (lambda: stats.wilson_interval(1, 10, confidence=0), "confidence"),
        (lambda: stats.wilson_interval(-1, 10), "successes must be a non-negative integer"),
        (lambda: stats.newcombe_interval(3, 2, 1, 5), "x1 must be between 0 and n1=2"),
        (lambda: stats.signed_rank_critical(0), "n must be an integer ≥ 1"),
        (lambda: stats.signed_rank_critical(10, alpha=2), "alpha must be in the open interval"),
        (lambda: stats.dunn([1, 2], [3, 4], p_adjust="fdr"), "p_adjust must be one of"),
        (lambda: stats.friedman([1, 2, 3], [1, 2]), "one value per subject"),
        (lambda: stats.anova_oneway([1, math.inf], [2, 3]), "infinite"),
    ],
)
def test_bad_input_raises_clear_error(call, needle):
    with pytest.raises(StatsInputError) as exc:
        call()
    assert needle in str(exc.value)


def test_nan_dropped_and_counted():
    r = stats.rank_sum([1, 2, math.nan, 4], [3, math.nan, 5])
    assert r.nan_dropped == 2 and r.n_x == 3 and r.n_y == 2
    s = stats.signed_rank([1, 2, math.nan, 4], [0, math.nan, 1, 1])
    assert s.nan_dropped == 2 and s.n == 2


def test_rm_anova_matches_statsmodels_anovarm():
    import numpy as np
    import pandas as pd
    from statsmodels.stats.anova import AnovaRM  # the reference; imported here, not at collection

    rng = np.random.default_rng(5)
    y = rng.normal(size=(10, 4)) + np.arange(4) * 0.5 + rng.normal(size=(10, 1))
    df = pd.DataFrame({"subject": np.repeat(np.arange(10), 4), "cond": np.tile(np.arange(4), 10), "y": y.ravel()})
    ref = AnovaRM(df, "y", "subject", within=["cond"]).fit().anova_table
    res = stats.rm_anova(*y.T)
    assert res.statistic == pytest.approx(ref["F Value"].iloc[0], rel=1e-10)
    assert res.pvalue == pytest.approx(ref["Pr > F"].iloc[0], rel=1e-9)
    assert 1 / 3 <= res.epsilon_gg <= 1 and res.pvalue_gg >= res.pvalue


def test_rm_anova_identical_subjects_are_zero_residual_not_rounding_noise():
    # Four virtual people with the same means (11/3 is not exact in binary): the residual is ~1e-31 of
    # rounding; it must read as zero residual variance, not F = 1e30 with a 0/0 Greenhouse-Geisser epsilon.
    import warnings

    row = [4.0, 0.0, 3.0, 4.0, 11.0 / 3.0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = stats.rm_anova(*zip(*[row] * 4, strict=True))
    assert res.statistic == math.inf and res.pvalue == 0.0 and res.degenerate
    assert "zero residual variance" in res.warnings
