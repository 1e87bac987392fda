"""Agreement with base R 4.2 (tests/reference/stats/r_reference.R → r_reference.csv)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl import stats

ALTS = {"two.sided": "two-sided", "less": "less", "greater": "greater"}
RS_CASES = {
    "r_example": ([0.80, 0.83, 1.89, 1.04, 1.45, 1.38, 1.91, 1.64, 0.73, 1.46], [1.15, 0.88, 0.90, 0.74, 1.21]),
    "case12": (list(range(1, 11)), list(range(2, 25, 2))),
    "sep10": (list(range(11, 21)), list(range(1, 11))),
    "sep50": (list(range(51, 101)), list(range(1, 51))),
    "n1": ([5], [1, 2, 3, 4]),
    "heavy": (
        [1] * 163 + [2] * 81 + [3] * 40 + [4] * 6 + [5] * 2,
        [1] * 1007 + [2] * 362 + [3] * 99 + [4] * 27 + [5] * 13,
    ),
}
SR_CASES = {
    "r_paired": list(np.array([1.83, 0.50, 1.62, 2.48, 1.68, 1.88, 1.55, 3.06, 1.30])
                     - np.array([0.878, 0.647, 0.598, 2.05, 1.06, 1.29, 1.06, 3.14, 1.29])),
    "tie5": [1, 1, 2, 3, 4],
    "zero5": [0, 1, 2, 3, 4],
    "pos55": list(range(1, 56)),
    "pos20": list(range(1, 21)),
}
TOL = 1e-9


def rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b) if b != 0 else abs(a)


def _rs(name, data):
    if name in RS_CASES:
        return RS_CASES[name]
    return data[name]["x"], data[name]["y"]


@pytest.mark.parametrize("name", ["mw_a", "mw_sep", "mw_ties", "mw_big", *RS_CASES])
@pytest.mark.parametrize("alt", list(ALTS))
@pytest.mark.parametrize("cc", [True, False])
def test_rank_sum_auto_matches_wilcox_test(name, alt, cc, rref, data):
    x, y = _rs(name, data)
    res = stats.rank_sum(x, y, alternative=ALTS[alt], continuity=cc)
    tag = f"{name}:{alt}:correct={str(cc).upper()}"
    assert res.statistic == rref[(tag, "statistic")]
    assert rel(res.pvalue, rref[(tag, "pvalue")]) <= TOL


@pytest.mark.parametrize("name", ["mw_a", "mw_ties", "mw_big", "r_example", "sep10"])
@pytest.mark.parametrize("alt", list(ALTS))
def test_rank_sum_asymptotic_matches(name, alt, rref, data):
    x, y = _rs(name, data)
    res = stats.rank_sum(x, y, alternative=ALTS[alt], method="asymptotic")
    assert res.method == "asymptotic"
    assert rel(res.pvalue, rref[(f"{name}:{alt}:asymptotic", "pvalue")]) <= TOL


@pytest.mark.parametrize("name", ["sr_a", "sr_ties", *SR_CASES])
@pytest.mark.parametrize("alt", list(ALTS))
@pytest.mark.parametrize("cc", [True, False])
def test_signed_rank_auto_matches_wilcox_test(name, alt, cc, rref, data):
    d = SR_CASES[name] if name in SR_CASES else data[name]["d"]
    res = stats.signed_rank(d, alternative=ALTS[alt], continuity=cc)
    tag = f"{name}:{alt}:correct={str(cc).upper()}"
    assert res.statistic == rref[(tag, "statistic")]
    assert rel(res.pvalue, rref[(tag, "pvalue")]) <= TOL


def test_signed_rank_exact_forced_matches_psignrank(rref):
    res = stats.signed_rank(list(range(1, 56)), method="exact")
    assert res.method == "exact"
    assert rel(res.pvalue, 2 * 2.0**-55) <= 1e-15
    assert rel(stats.signed_rank(list(range(1, 21))).pvalue, rref[("pos20:two.sided:exact", "pvalue")]) <= TOL


@pytest.mark.parametrize("n", range(6, 31))
def test_signed_rank_critical_matches_psignrank(n, rref):
    assert stats.signed_rank_critical(n) == rref[(f"wcrit:{n}", "two.sided_0.05")]
    assert stats.signed_rank_critical(n, alternative="greater") == rref[(f"wcrit:{n}", "one.sided_0.05")]
    r01 = rref[(f"wcrit:{n}", "two.sided_0.01")]
    got = stats.signed_rank_critical(n, alpha=0.01)
    assert (got is None and math.isnan(r01)) or got == r01


KW = {
    "case18a": [[1, 1, 1], [2, 2, 2], [2, 2]],
    "case18b": [[1, 3, 5, 7, 9], [2, 4, 6, 8, 10]],
    "singletons": [[1], [2], [3]],
}


def _groups(name, data):
    return KW[name] if name in KW else list(data[name].values())


@pytest.mark.parametrize("name", ["kw_a", "kw_likert", "warp", *KW])
def test_kruskal_and_dunn_match_r(name, rref, data):
    groups = _groups(name, data)
    res = stats.kruskal_wallis(*groups)
    assert rel(res.statistic, rref[(f"kw:{name}", "statistic")]) <= TOL
    assert rel(res.pvalue, rref[(f"kw:{name}", "pvalue")]) <= TOL
    for method, key in [("holm", "holm"), ("bonferroni", "bonferroni"), ("bh", "BH"), ("tukey-kramer", "tukey")]:
        dn = stats.dunn(*groups, p_adjust=method)
        for m in range(len(dn.z)):
            assert rel(dn.z[m], rref[(f"dunn:{name}", f"z{m + 1}")]) <= TOL
            assert rel(dn.pvalue[m], rref[(f"dunn:{name}", f"p{m + 1}")]) <= TOL
            tol = 1e-6 if key == "tukey" else TOL  # ptukey itself is approximate
            assert rel(dn.p_adj[m], rref[(f"dunn:{name}", f"{key}{m + 1}")]) <= tol


@pytest.mark.parametrize("name", ["anova_5x12", "anova_unequal", "warp", "kw_a"])
def test_anova_and_tukey_match_r(name, rref, data):
    groups = data[name]
    a = stats.anova_oneway(groups)
    assert rel(a.statistic, rref[(f"anova:{name}", "statistic")]) <= TOL
    assert rel(a.pvalue, rref[(f"anova:{name}", "pvalue")]) <= TOL
    shifted = {k: [v + 1e9 for v in vals] for k, vals in groups.items()}
    assert rel(stats.anova_oneway(shifted).statistic, a.statistic) <= 1e-6  # data rounded at 1e9 + x
    t = stats.tukey_hsd(groups).to_frame()
    for m, row in enumerate(t.itertuples()):
        assert rel(row.diff, rref[(f"tukey:{name}", f"diff{m + 1}")]) <= TOL
        assert rel(row.p_adj, rref[(f"tukey:{name}", f"p adj{m + 1}")]) <= 1e-6
        # R's qtukey stops its secant search at |Δq| < 1e-4, so its limits are good to ~1e-4·SE
        assert abs(row.lower - rref[(f"tukey:{name}", f"lwr{m + 1}")]) <= 2e-4 * (row.upper - row.lower)
        assert abs(row.upper - rref[(f"tukey:{name}", f"upr{m + 1}")]) <= 2e-4 * (row.upper - row.lower)


@pytest.mark.parametrize("q", [0.5, 1, 2, 3.5, 5, 8])
@pytest.mark.parametrize("k", [2, 3, 5, 10])
@pytest.mark.parametrize("df", [2, 5, 10, 30, 120, math.inf])
def test_studentized_range_sf_matches_ptukey(q, k, df, rref):
    ref = rref[(f"ptukey:{q:g}:{k:g}:{'Inf' if math.isinf(df) else f'{df:g}'}", "sf")]
    got = stats.studentized_range_sf(q, k, df)
    if df == 2:
        # R's ptukey is documented as less accurate for small df: at k = 2 it misses the exact
        # identity 2·P(t_2 > q/√2) by up to 4e-3 relative; ours meets it (see test_hard_cases).
        assert rel(got, ref) <= 5e-3
    else:
        # elsewhere R agrees to 1e-6 relative or 1e-7 absolute (its upper tail is 1 − lower tail)
        assert rel(got, ref) <= 1e-6 or abs(got - ref) <= 1e-7


def test_friedman_matches_r(rref, data):
    res = stats.friedman(*data["rm_4x10"].values())
    assert rel(res.statistic, rref[("friedman:rm_4x10", "statistic")]) <= TOL
    assert rel(res.pvalue, rref[("friedman:rm_4x10", "pvalue")]) <= TOL


@pytest.mark.parametrize("xn", [(0, 10), (10, 10), (81, 263), (15, 148), (1, 29), (50, 60), (30, 60), (47, 60)])
def test_wilson_matches_r_formula(xn, rref):
    ci = stats.wilson_interval(*xn)
    assert abs(ci.lower - rref[(f"wilson:{xn[0]}:{xn[1]}", "lower")]) <= 1e-12
    assert abs(ci.upper - rref[(f"wilson:{xn[0]}:{xn[1]}", "upper")]) <= 1e-12
