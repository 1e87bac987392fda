"""Hypothesis property tests: p in [0, 1], mirror symmetry, invariance to monotone transforms."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from studyctl import stats

small = st.lists(st.integers(-20, 20), min_size=1, max_size=12)
ALTS = ("two-sided", "less", "greater")
FAST = settings(max_examples=60, deadline=None)


@FAST
@given(small, small, st.sampled_from(ALTS), st.sampled_from(["auto", "exact", "asymptotic"]))
def test_rank_sum_p_in_unit_interval_and_mirror(x, y, alt, method):
    a = stats.rank_sum(x, y, alternative=alt, method=method)
    mirror = {"less": "greater", "greater": "less", "two-sided": "two-sided"}[alt]
    b = stats.rank_sum(y, x, alternative=mirror, method=method)
    if a.degenerate:
        assert math.isnan(a.pvalue) and b.degenerate
        return
    assert 0.0 <= a.pvalue <= 1.0
    assert math.isclose(a.pvalue, b.pvalue, rel_tol=1e-12, abs_tol=1e-300)
    assert a.effect_size == -b.effect_size


@FAST
@given(small, small)
def test_rank_sum_invariant_to_monotone_transform(x, y):
    a = stats.rank_sum(x, y, method="exact")
    b = stats.rank_sum(np.exp(np.array(x) / 7.0), np.exp(np.array(y) / 7.0) * 1.0, method="exact")
    assert a.statistic == b.statistic
    assert (math.isnan(a.pvalue) and math.isnan(b.pvalue)) or a.pvalue == b.pvalue


@FAST
@given(small, st.sampled_from(ALTS), st.sampled_from(["wilcox", "pratt", "zsplit"]),
       st.sampled_from(["auto", "exact", "asymptotic"]))
def test_signed_rank_p_in_unit_interval_and_sign_flip(d, alt, zm, method):
    a = stats.signed_rank(d, alternative=alt, zero_method=zm, method=method)
    mirror = {"less": "greater", "greater": "less", "two-sided": "two-sided"}[alt]
    b = stats.signed_rank([-v for v in d], alternative=mirror, zero_method=zm, method=method)
    if a.degenerate:
        assert math.isnan(a.pvalue)
        return
    assert 0.0 <= a.pvalue <= 1.0
    assert math.isclose(a.pvalue, b.pvalue, rel_tol=1e-12)
    assert math.isclose(a.effect_size, -b.effect_size, abs_tol=1e-15)


@FAST
@given(st.lists(small, min_size=2, max_size=4))
def test_kruskal_and_dunn_group_order_and_transform(groups):
    a = stats.kruskal_wallis(*groups)
    b = stats.kruskal_wallis(*groups[::-1])
    c = stats.kruskal_wallis(*[list(np.array(g) ** 3) for g in groups])
    if a.degenerate:
        assert b.degenerate and c.degenerate
        return
    assert a.statistic == b.statistic == c.statistic and 0 <= a.pvalue <= 1
    d = stats.dunn(*groups)
    assert np.all((d.p_adj >= 0) & (d.p_adj <= 1))


@FAST
@given(st.lists(st.lists(st.integers(-50, 50), min_size=2, max_size=8), min_size=2, max_size=4),
       st.sampled_from([0.0, 1e9, 1e12]))
def test_anova_and_tukey_offset_and_order(groups, offset):
    a = stats.anova_oneway(*groups)
    b = stats.anova_oneway(*[list(np.array(g, dtype=float) + offset) for g in groups[::-1]])
    if a.degenerate:
        assert b.degenerate
        return
    assert math.isclose(a.statistic, b.statistic, rel_tol=1e-12) and 0 <= a.pvalue <= 1
    t = stats.tukey_hsd(*groups)
    assert np.all((t.p_adj >= 0) & (t.p_adj <= 1)) and np.all(t.lower <= t.upper)


@FAST
@given(st.integers(0, 200), st.integers(0, 200), st.floats(0.5, 0.999))
def test_wilson_bounds(x, extra, conf):
    n = x + extra
    ci = stats.wilson_interval(x, n, conf)
    if n == 0:
        assert math.isnan(ci.lower)
        return
    assert 0.0 <= ci.lower <= ci.estimate <= ci.upper <= 1.0
    assert (ci.lower == 0.0) == (x == 0) and (ci.upper == 1.0) == (x == n)


@FAST
@given(st.integers(0, 60), st.integers(1, 60), st.integers(0, 60), st.integers(1, 60))
def test_newcombe_swap(x1, n1, x2, n2):
    x1, x2 = min(x1, n1), min(x2, n2)
    a = stats.newcombe_interval(x1, n1, x2, n2)
    b = stats.newcombe_interval(x2, n2, x1, n1)
    assert a.lower == -b.upper and a.upper == -b.lower and -1 <= a.lower <= a.difference <= a.upper <= 1
