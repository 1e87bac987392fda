"""The 31 hard cases of shared/research/stats.md §4, the seed papers' published numbers, and
the independent exact references (tests/reference/stats/exact_reference.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl import stats


def rel(a, b):
    return abs(a - b) / abs(b) if b else abs(a)


# 1
def test_01_signed_rank_exact_all_positive_and_negative_n55():
    for d in (np.arange(1, 56), -np.arange(1, 56)):
        r = stats.signed_rank(d, method="exact")
        assert r.pvalue > 0 and rel(r.pvalue, 2 * 2.0**-55) < 1e-15


# 2
def test_02_w_critical_table_and_definition():
    table = {6: 0, 7: 2, 8: 3, 9: 5, 10: 8, 11: 10, 12: 13, 13: 17, 14: 21, 15: 25, 16: 29, 17: 34, 18: 40, 19: 46,
             20: 52, 21: 58, 22: 65, 23: 73, 24: 81, 25: 89, 26: 98, 27: 107, 28: 116, 29: 126, 30: 137}
    for n, w in table.items():
        assert stats.signed_rank_critical(n) == w
        counts = np.array(stats.signed_rank(np.arange(1, n + 1), method="exact").n_used)  # noqa: F841
        from studyctl.stats._exact import signed_rank_cdf

        cdf = signed_rank_cdf(n)
        assert cdf[w] <= 0.025 < cdf[w + 1]
    for n in range(1, 6):
        assert stats.signed_rank_critical(n) is None


# 3
def test_03_r_paired_example():
    x = [1.83, 0.50, 1.62, 2.48, 1.68, 1.88, 1.55, 3.06, 1.30]
    y = [0.878, 0.647, 0.598, 2.05, 1.06, 1.29, 1.06, 3.14, 1.29]
    r = stats.signed_rank(x, y, alternative="greater")
    assert (r.statistic, r.pvalue, r.method) == (40.0, 0.01953125, "exact")


# 4
def test_04_tie_auto_is_r_and_exact_is_conditional():
    r = stats.signed_rank([1, 1, 2, 3, 4])
    assert r.method == "asymptotic" and r.warnings and abs(r.pvalue - 0.05791) < 1e-5
    e = stats.signed_rank([1, 1, 2, 3, 4], method="exact")
    assert e.conditional and e.pvalue == 0.0625


# 5
def test_05_zero_dropped_like_r():
    r = stats.signed_rank([0, 1, 2, 3, 4])
    assert r.statistic == 10 and abs(r.pvalue - 0.1003) < 1e-4 and r.n_zero == 1
    assert stats.signed_rank([0, 1, 2, 3, 4], method="exact").pvalue == 0.125


# 6
def test_06_all_zero_differences():
    r = stats.signed_rank([0.0, 0.0, 0.0])
    assert r.statistic == 0 and math.isnan(r.pvalue) and r.degenerate and r.warnings


# 7
def test_07_pratt_many_zeros():
    r = stats.signed_rank([1] * 5 + [0] * 40 + [-1] * 5, zero_method="pratt")
    assert r.pvalue == 1.0


# 8
def test_08_float_zero_option():
    x = np.array([0.1, 0.2, 0.7, 1.0]) + 0.2 - 0.1
    y = np.array([0.2, 0.5, 0.3, 0.6]) + 0.0
    x[0] = 0.1 + 0.2 - 0.1
    y[0] = 0.2
    raw = stats.signed_rank(x, y)
    fixed = stats.signed_rank(x, y, decimals=12)
    assert raw.n_zero == 0 and fixed.n_zero == 1


# 9
def test_09_small_n_minimum_p():
    assert stats.signed_rank([1, 2, 3, 4, 5]).pvalue == 0.0625
    assert stats.signed_rank([1, 2, 3, 4, 5, 6]).pvalue == 0.03125


# 10
@pytest.mark.parametrize("n,p", [(10, 1.0825e-05), (20, 1.4509e-11), (50, 1.98e-29)])
def test_10_complete_separation_exact(n, p):
    r = stats.rank_sum(np.arange(n) + n, np.arange(n), method="exact")
    assert rel(r.pvalue, p) < 5e-3  # printed digits
    assert rel(r.pvalue, 2 / math.comb(2 * n, n)) < 1e-12


# 11
def test_11_r_rank_sum_example():
    r = stats.rank_sum([0.80, 0.83, 1.89, 1.04, 1.45, 1.38, 1.91, 1.64, 0.73, 1.46], [1.15, 0.88, 0.90, 0.74, 1.21],
                       alternative="greater")
    assert r.statistic == 35 and abs(r.pvalue - 0.1272061) < 1e-7


# 12
@pytest.mark.parametrize("alt,p", [("two-sided", 0.01188904), ("less", 0.006001738), ("greater", 0.9949199)])
def test_12_exact_conditional_matches_coin(alt, p, xref):
    r = stats.rank_sum(np.arange(1, 11), np.arange(2, 25, 2), method="exact", alternative=alt)
    assert r.conditional and abs(r.pvalue - p) < 5e-8  # coin's printed digits
    assert rel(r.pvalue, xref[("ranksum_exact:case12", alt.replace("-", "."))]) < 1e-12


# 13
def test_13_all_tied_rank_sum():
    r = stats.rank_sum([3, 3, 3], [3, 3])
    assert math.isnan(r.pvalue) and r.degenerate and r.statistic == 3.0


# 14
def test_14_single_x():
    r = stats.rank_sum([5], [1, 2, 3, 4])
    assert r.statistic == 4 and rel(r.pvalue, 0.4) < 1e-15


# 15
def test_15_heavy_ties_no_overflow():
    x = [1] * 163 + [2] * 81 + [3] * 40 + [4] * 6 + [5] * 2
    y = [1] * 1007 + [2] * 362 + [3] * 99 + [4] * 27 + [5] * 13
    r = stats.rank_sum(x, y)
    assert r.statistic == 246930.5 and abs(r.pvalue - 9.349e-5) < 1e-7
    k = stats.kruskal_wallis(x, y)
    assert abs(k.statistic - 15.264) < 1e-3 and abs(k.pvalue - 9.346e-5) < 1e-7


# 16
def test_16_one_comparison_does_not_depend_on_another():
    a = stats.rank_sum([1.5, 2.5, 3.5, 8.0], [0.2, 0.9, 4.4])
    stats.rank_sum([1, 1, 2, 2], [1, 2, 2, 3])  # tied data in between
    b = stats.rank_sum([1.5, 2.5, 3.5, 8.0], [0.2, 0.9, 4.4])
    assert a == b and a.method == "exact"


# 17
def test_17_kw_all_identical():
    r = stats.kruskal_wallis([2, 2], [2, 2, 2], [2])
    assert math.isnan(r.statistic) and math.isnan(r.pvalue) and r.degenerate and r.warnings


# 18
def test_18_kw_values():
    r = stats.kruskal_wallis([1, 1, 1], [2, 2, 2], [2, 2])
    assert abs(r.statistic - 7.0) < 1e-12 and abs(r.pvalue - 0.030197) < 1e-6
    r = stats.kruskal_wallis([1, 3, 5, 7, 9], [2, 4, 6, 8, 10])
    assert abs(r.statistic - 0.27273) < 1e-5 and abs(r.pvalue - 0.60151) < 1e-5


# 19
def test_19_kw_two_groups_equals_rank_sum_and_dunn():
    x, y = [1.2, 3.4, 2.2, 5.1, 4.4, 0.3], [2.5, 6.1, 7.7, 5.5, 8.0]
    k = stats.kruskal_wallis(x, y)
    m = stats.rank_sum(x, y, method="asymptotic", continuity=False)
    d = stats.dunn(x, y, p_adjust="none")
    assert rel(k.pvalue, m.pvalue) < 1e-12 and rel(k.statistic, m.z**2) < 1e-12
    assert rel(abs(d.z[0]), abs(m.z)) < 1e-12


# 20
def test_20_kw_identical_groups_and_singletons():
    r = stats.kruskal_wallis([1, 2, 3, 4], [1, 2, 3, 4])
    assert r.statistic == 0.0 and r.pvalue == 1.0
    r = stats.kruskal_wallis([1], [2], [3])
    assert abs(r.statistic - 2.0) < 1e-12 and abs(r.pvalue - 0.367879) < 1e-6


# 21
def test_21_large_tied_data():
    rng = np.random.default_rng(3)
    g = [rng.integers(0, 5, 30000) for _ in range(3)]
    r = stats.kruskal_wallis(*g)
    d = stats.dunn(*g)
    assert np.isfinite(r.statistic) and 0 <= r.pvalue <= 1
    assert np.all(np.isfinite(d.z)) and np.all((d.p_adj >= 0) & (d.p_adj <= 1))
    likert = [rng.integers(1, 6, 367) for _ in range(3)]
    assert np.isfinite(stats.kruskal_wallis(*likert).statistic)


# 22
def test_22_dunn_holm_monotone_two_sided_and_nan_padding():
    from scipy import stats as sps
    g = [[1, 2, 3, 4, 5], [3, 4, 5, 6, 7, 8], [7, 8, 9, 10, 11], [2, 3, 3, 4]]
    d = stats.dunn(*g)
    order = np.argsort(d.pvalue)
    assert np.all(np.diff(d.p_adj[order]) >= 0)
    assert np.allclose(d.pvalue, 2 * sps.norm.sf(np.abs(d.z)))
    padded = stats.dunn(*[v + [math.nan] * 3 for v in g])
    assert np.array_equal(padded.p_adj, d.p_adj) and padded.nan_dropped == 12


# 23
def test_23_matlab_multcompare_variant():
    g = [[1, 2, 3, 4, 5], [3, 4, 5, 6, 7, 8], [7, 8, 9, 10, 11]]
    d = stats.dunn(*g, p_adjust="tukey-kramer")
    expect = stats.studentized_range_sf(math.sqrt(2) * np.abs(d.z), 3, math.inf)
    assert np.allclose(d.p_adj, expect, rtol=1e-14)
    b = stats.dunn(*g, p_adjust="bonferroni")
    assert np.allclose(b.p_adj, np.minimum(1, 3 * b.pvalue))


# 24
def test_24_anova_constant_groups():
    g = [[2] * 10, [1000] * 5, [100] * 6]
    for order in ([0, 1, 2], [2, 0, 1], [1, 2, 0]):
        r = stats.anova_oneway(*[g[i] for i in order])
        assert r.statistic == math.inf and r.pvalue == 0.0 and r.degenerate
    r = stats.anova_oneway([3, 3], [3, 3, 3])
    assert math.isnan(r.statistic) and r.degenerate


# 25
@pytest.mark.parametrize("offset", [0.0, 1e9, 1e12])
def test_25_anova_offset_invariance(offset):
    r = stats.anova_oneway(np.array([1, 2, 3]) + offset, np.array([4, 5, 6]) + offset)
    assert r.statistic == 13.5 and abs(r.pvalue - 0.0213116) < 1e-7


# 26
def test_26_tukey_warpbreaks():
    l_ = [26, 30, 54, 25, 70, 52, 51, 26, 67, 27, 14, 29, 19, 29, 31, 41, 20, 44]
    m = [18, 21, 29, 17, 12, 18, 35, 30, 36, 42, 26, 19, 16, 39, 28, 21, 39, 29]
    h = [36, 21, 24, 18, 10, 43, 28, 15, 26, 20, 21, 24, 17, 13, 15, 15, 16, 28]
    t = stats.tukey_hsd(l_, m, h, names=["L", "M", "H"]).to_frame()
    assert list(t.columns) == ["group1", "group2", "diff", "lower", "upper", "p_adj"]
    for got, printed, tol in zip(t.p_adj, [0.03846, 0.001432, 0.4631], [5e-6, 5e-7, 5e-5], strict=True):
        assert abs(got - printed) <= tol
    assert abs(-t.upper[0] - 0.4402) < 1e-4 and abs(-t.lower[0] - 19.5598) < 1e-4  # CI of L − M
    a = stats.anova_oneway(l_, m, h)
    assert abs(a.statistic - 7.2061) < 1e-4 and abs(a.pvalue - 0.0017528) < 1e-7


# 27
def test_27_studentized_range(xref):
    from scipy import stats as sps
    assert abs(stats.studentized_range_sf(3.5, 3, 10) - 0.0771033) < 1e-7
    assert rel(stats.studentized_range_sf(20, 3, 20), 2.08674e-11) < 1e-5
    assert 7.3e-48 < stats.studentized_range_sf(40, 10, 100) < 7.4e-48
    assert rel(stats.studentized_range_sf(8, 2, 12), 2 * sps.t.sf(8 / math.sqrt(2), 12)) < 1e-14
    assert rel(stats.studentized_range_sf(8, 2, 12), 1.06122e-4) < 1e-5
    qs = np.linspace(0.1, 12, 60)
    assert np.all(np.diff(stats.studentized_range_sf(qs, 5, 20)) < 0)
    assert abs(stats.studentized_range_ppf(0.95, 3, 10) - 3.8768) < 1e-4
    for (case, _key), v in xref.items():
        if case.startswith("range_sf:"):
            _, w, k = case.split(":")
            from studyctl.stats.studentized_range import log_range_sf

            assert rel(math.exp(float(log_range_sf(np.array(float(w)), int(k)))), v) < 1e-10
        if case.startswith("ptukey_sf:"):
            _, q, k, df = case.split(":")
            assert rel(stats.studentized_range_sf(float(q), int(k), float(df)), v) < 1e-9


# 28
def test_28_tukey_zero_variance():
    t = stats.tukey_hsd([1, 1, 1], [2, 2, 2], [2, 2])
    assert t.degenerate and t.warnings
    assert list(t.p_adj[:2]) == [0.0, 0.0] and math.isnan(t.p_adj[2])


# 29
def test_29_wilson():
    ci = stats.wilson_interval(0, 10)
    assert ci.lower == 0.0 and abs(ci.upper - 0.277533) < 1e-6
    ci = stats.wilson_interval(10, 10)
    assert ci.upper == 1.0 and abs(ci.lower - 0.722467) < 1e-6
    for x, n, lo, hi in [(81, 263, 0.2553, 0.3662), (15, 148, 0.0624, 0.1605), (1, 29, 0.0061, 0.1718)]:
        ci = stats.wilson_interval(x, n)
        assert abs(ci.lower - lo) < 5e-5 and abs(ci.upper - hi) < 5e-5
    ci = stats.wilson_interval(0, 0)
    assert math.isnan(ci.lower) and math.isnan(ci.upper)
    tiny = stats.wilson_interval(1, 10**12)
    assert tiny.lower > 0 and tiny.upper < 1


# 30
@pytest.mark.parametrize(
    "x1,n1,x2,n2,lo,hi",
    [(56, 70, 48, 80, 0.0524, 0.3339), (9, 10, 3, 10, 0.1705, 0.8090), (6, 7, 2, 7, 0.0582, 0.8062),
     (5, 56, 0, 29, -0.0381, 0.1926), (0, 10, 0, 20, -0.1611, 0.2775), (10, 10, 0, 20, 0.6791, 1.0)],
)
def test_30_newcombe_table_ii(x1, n1, x2, n2, lo, hi, xref):
    ci = stats.newcombe_interval(x1, n1, x2, n2)
    assert abs(ci.lower - lo) < 5e-5 and abs(ci.upper - hi) < 5e-5
    tag = f"newcombe:{x1}/{n1}-{x2}/{n2}"
    assert abs(ci.lower - xref[(tag, "lower")]) < 1e-14 and abs(ci.upper - xref[(tag, "upper")]) < 1e-14
    sw = stats.newcombe_interval(x2, n2, x1, n1)
    assert sw.lower == -ci.upper and sw.upper == -ci.lower and sw.difference == -ci.difference


# 31
def test_31_invariances():
    x, y = [3.1, 4.5, 2.2, 8.9, 5.5], [1.0, 2.5, 0.4, 3.3, 2.2, 1.9]
    a = stats.rank_sum(x, y, alternative="greater")
    b = stats.rank_sum(y, x, alternative="less")
    assert a.pvalue == b.pvalue and a.effect_size == -b.effect_size
    ex = stats.rank_sum(np.exp(x), np.exp(y), alternative="greater")
    assert ex.pvalue == a.pvalue and ex.statistic == a.statistic
    g = [[1.0, 2.5, 3.3], [4.1, 5.2, 3.9, 6.0], [2.2, 2.9, 7.5]]
    for f in (stats.kruskal_wallis, stats.anova_oneway):
        assert f(*g).statistic == f(*g[::-1]).statistic
    t1 = stats.tukey_hsd(*g).to_frame()
    t2 = stats.tukey_hsd(g[2], g[0], g[1], names=["3", "1", "2"]).to_frame()
    for row in t1.itertuples():
        match = t2[((t2.group1 == row.group1) & (t2.group2 == row.group2))
                   | ((t2.group1 == row.group2) & (t2.group2 == row.group1))]
        assert abs(abs(match["diff"].iloc[0]) - abs(row.diff)) < 1e-12
        assert abs(match["p_adj"].iloc[0] - row.p_adj) < 1e-12


# seed papers (shared/reference_values.md)
def test_seed003_wilson_intervals_to_printed_digits():
    # the paper rounds limits outwards to 0.1 %: floor the lower, ceil the upper
    for x, lo, hi in [(50, 71.9, 90.7), (30, 37.7, 62.3), (47, 66.3, 86.9)]:
        ci = stats.wilson_interval(x, 60)
        assert math.floor(ci.lower * 1000) / 10 == lo and math.ceil(ci.upper * 1000) / 10 == hi


def test_seed003_newcombe_margins():
    counts = {"manual": 50, "FF": 47, "PHF": 30, "combination": 50}
    for a, b, margin, dp in [("manual", "FF", 0.142, 0.050), ("manual", "PHF", 0.167, 0.333),
                             ("FF", "PHF", 0.171, 0.283), ("FF", "combination", 0.142, 0.050),
                             ("PHF", "combination", 0.167, 0.333)]:
        ci = stats.newcombe_interval(counts[a], 60, counts[b], 60)
        assert round(ci.margin, 3) == margin and round(abs(ci.difference), 3) == dp
        assert ci.excludes_zero == (abs(ci.difference) > ci.margin)
    eq = stats.newcombe_interval(50, 60, 50, 60)
    assert eq.difference == 0 and math.isnan(eq.margin) and not eq.excludes_zero


def test_seed003_w_critical():
    assert [stats.signed_rank_critical(n) for n in (18, 19, 20)] == [40, 46, 52]


def test_seed002_u_test_normal_approximation():
    # U = 133 with n1 = n2 = 20: z = (133 − 200)/36.97 → p ≈ 0.070, 0.072 with continuity correction
    x = np.arange(1, 41, dtype=float)
    # build a sample whose U is 133: ranks of x chosen so that Σ ranks − 210 = 133
    ranks = list(range(1, 21))
    extra = 133
    for i in range(19, -1, -1):
        step = min(extra, 20)
        ranks[i] += step
        extra -= step
    xs = [x[r - 1] for r in ranks]
    ys = [v for v in x if v not in xs]
    r = stats.rank_sum(xs, ys, method="asymptotic")
    assert r.statistic == 133
    assert round(r.pvalue, 3) == 0.072
    assert round(stats.rank_sum(xs, ys, method="asymptotic", continuity=False).pvalue, 3) == 0.070
    assert abs(stats.rank_sum(xs, ys).pvalue - 0.071) < 0.002  # exact (both n < 50, no ties)


# exact references with ties (brute force / exact integers)
@pytest.mark.parametrize("name", ["mw_ties", "small_ties"])
@pytest.mark.parametrize("alt", ["two-sided", "less", "greater"])
def test_rank_sum_exact_conditional_vs_enumeration(name, alt, xref, data):
    x, y = (data["mw_ties"]["x"], data["mw_ties"]["y"]) if name == "mw_ties" else (
        [1, 2, 2, 3, 5, 5], [2, 3, 3, 4, 6, 6, 7])
    r = stats.rank_sum(x, y, method="exact", alternative=alt)
    assert rel(r.pvalue, xref[(f"ranksum_exact:{name}", alt.replace("-", "."))]) < 1e-12


@pytest.mark.parametrize("name,d,zm", [
    ("tie5", [1, 1, 2, 3, 4], "wilcox"), ("zero5", [0, 1, 2, 3, 4], "wilcox"),
    ("zero5_pratt", [0, 1, 2, 3, 4], "pratt"), ("mixed12", [1, 1, 2, -2, 3, 0, 4, -1, 5, 5, 6, 0], "pratt"),
    ("sr_ties", None, "wilcox"), ("sr_ties_pratt", None, "pratt")])
@pytest.mark.parametrize("alt", ["two-sided", "less", "greater"])
def test_signed_rank_exact_conditional_vs_enumeration(name, d, zm, alt, xref, data):
    d = data["sr_ties"]["d"] if d is None else d
    r = stats.signed_rank(d, method="exact", zero_method=zm, alternative=alt)
    assert rel(r.pvalue, xref[(f"signedrank_exact:{name}", alt.replace("-", "."))]) < 1e-12


@pytest.mark.parametrize("m,n", [(60, 70), (200, 200)])
def test_untied_rank_sum_tails_vs_exact_integers(m, n, xref):
    from studyctl.stats._exact import rank_sum_untied_le

    for (case, key), v in xref.items():
        if case == f"ranksum_untied:{m}x{n}":
            u = int(key.split("_")[1])
            assert rel(rank_sum_untied_le(u, m, n), v) < 1e-12
