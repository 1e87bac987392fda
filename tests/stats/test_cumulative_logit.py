"""The Newton-Raphson cumulative logit fit against closed forms, against statsmodels' OrderedModel (an independent
implementation: BFGS on numerical gradients) and on hard tables. R's clm values are in test_models.py."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pandas as pd
import pytest

from studyctl.errors import StatsInputError
from studyctl.stats.cumulative_logit import count_table, fit_cumulative_logit, null_llf
from studyctl.stats.models import ordinal_model


def _statsmodels_fit(counts: np.ndarray) -> tuple[float, np.ndarray]:
    from statsmodels.miscmodels.ordinal_model import OrderedModel

    levels, cats = np.nonzero(counts)
    reps = counts[levels, cats]
    level, y = np.repeat(levels, reps), np.repeat(cats, reps)
    yc = pd.Series(pd.Categorical(y, categories=range(counts.shape[1]), ordered=True))
    x = pd.DataFrame({f"l{v}": (level == v).astype(float) for v in range(1, counts.shape[0])})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = OrderedModel(yc, x, distr="logit").fit(method="bfgs", disp=False, maxiter=5000, gtol=1e-10)
    return float(res.llf), np.asarray(res.params)[: x.shape[1]]


def test_two_by_two_is_the_saturated_logistic_regression_even_at_extreme_counts():
    # two answers, two levels: θ = logit of the reference's proportion, β its log odds ratio; closed forms
    for n, m in ((7, 3), (10**6, 1), (10**7, 2)):
        counts = np.array([[n, m], [m, n]])
        fit = fit_cumulative_logit(counts)
        want_llf = 2 * (n * math.log1p(-m / (n + m)) + m * math.log(m / (n + m)))
        assert not fit.separated and fit.converged
        # 1e-8: with 10⁷ answers the gradient's rounding (~1e-16 × 10⁷) leaves β known to ~1e-9 of ~30
        assert fit.coef[0] == pytest.approx(2 * math.log(n / m), rel=1e-8)
        assert fit.thresholds[0] == pytest.approx(math.log(n / m), rel=1e-8)
        assert fit.llf == pytest.approx(want_llf, rel=1e-12)
        assert fit.coef_cov[0, 0] == pytest.approx(2 * (1 / n + 1 / m), rel=1e-8)  # Woolf's variance


def test_separated_levels_are_flagged_and_the_likelihood_reaches_its_supremum():
    # level 1 answers only the top category: β → ∞, level 0 keeps its own proportions (the supremum, closed form)
    fit = fit_cumulative_logit(np.array([[3, 2, 1, 0], [0, 0, 0, 5]]))
    assert fit.separated and fit.cov is None and fit.coef_cov is None
    assert fit.llf == pytest.approx(3 * math.log(1 / 2) + 2 * math.log(1 / 3) + math.log(1 / 6), abs=1e-9)
    # the reference level at the bottom: both other levels diverge
    assert fit_cumulative_logit(np.array([[4, 0, 0], [2, 3, 1], [1, 2, 3]])).separated
    # overlap: finite estimates, covariance given
    regular = fit_cumulative_logit(np.array([[5, 3, 2, 1], [2, 3, 4, 3], [1, 2, 3, 6]]))
    assert not regular.separated and regular.steps < 10 and np.all(np.diag(regular.cov) > 0)


def test_agrees_with_statsmodels_on_random_tables():
    rng = np.random.default_rng(20261129)
    checked = 0
    for _ in range(40):
        levels, cats = int(rng.integers(2, 5)), int(rng.integers(2, 7))
        counts = rng.integers(0, 9, size=(levels, cats)) + rng.integers(0, 2, size=(levels, 1))
        counts[:, 0] += counts.sum(axis=1) == 0
        counts[0] += counts.sum(axis=0) == 0
        fit = fit_cumulative_logit(counts)
        llf, coef = _statsmodels_fit(counts)
        assert fit.llf >= llf - 1e-9  # never below the other optimiser's maximum
        if not fit.separated:
            assert fit.llf == pytest.approx(llf, abs=1e-8)
            assert np.allclose(fit.coef, coef, atol=1e-5)
            checked += 1
    assert checked >= 25


def test_thresholds_only_llf_and_count_table():
    values = np.array([1, 2, 2, 3, 5, 5, 5.0])
    counts, cats = count_table(values, np.array(list("abbaabb")), ["b", "a"])
    assert list(cats) == [1, 2, 3, 5] and counts.tolist() == [[0, 2, 0, 2], [1, 0, 1, 1]]
    assert null_llf(counts.sum(axis=0)) == pytest.approx(2 * math.log(2 / 7) * 1 + 2 * math.log(1 / 7)
                                                         + 3 * math.log(3 / 7))


@pytest.mark.parametrize("counts", [[[1], [2]], [[1, -1], [2, 2]], [[1.5, 1], [1, 1]], [[1, 0], [2, 0]],
                                    [[0, 0], [1, 2]]])
def test_tables_without_a_model_are_refused(counts):
    with pytest.raises(StatsInputError):
        fit_cumulative_logit(np.array(counts))


def test_the_likelihood_ratio_term_says_when_a_level_is_separated():
    y = [1, 1, 2, 2, 3, 5, 5, 5, 5, 5]
    (t,) = ordinal_model(y, ["A"] * 5 + ["B"] * 5).terms
    assert t.status != "not_computed" and "separated" in t.reason and t.statistic > 0
