"""Rank tests: Wilcoxon rank-sum and signed-rank, Kruskal-Wallis with Dunn's comparisons, Friedman."""

from __future__ import annotations

import dataclasses

from studyctl import stats
from studyctl.analysis.procedures.spec import (
    BETWEEN,
    EACH_PAIR,
    WITHIN,
    Cell,
    Finding,
    TestSpec,
    below,
    pair_index,
)

_ALT = frozenset({"alternative"})


def _rank_sum(cell: Cell) -> list[Finding]:
    x, y = cell.samples
    res = stats.rank_sum(x, y, **cell.options)
    s = res.summary()
    return [Finding(s, below(s.p, cell.alpha), warnings=s.warnings)]


def _signed_rank(cell: Cell) -> list[Finding]:
    """V (R+) and its p; with ``critical_value``, the decision W = min(R+, R−) ≤ the exact W_critical."""
    opts = dict(cell.options)
    critical = bool(opts.pop("critical_value", False))
    x, y = cell.samples
    res = stats.signed_rank(x, y, **opts)
    s = res.summary()
    if not critical:
        return [Finding(s, below(s.p, cell.alpha), warnings=s.warnings)]
    n_r = int(res.n_used)
    crit = stats.signed_rank_critical(n_r, alpha=cell.alpha)
    notes = () if crit is not None else (f"no exact critical value exists for n_r = {n_r} at alpha {cell.alpha}",)
    s = dataclasses.replace(
        s,
        statistic_name="W = min(R+, R-)",
        statistic=float(res.w_min),
        df=float(n_r),
        method=f"{s.method}; decision W <= W_critical (n_r = {n_r} non-zero pairs)",
    )
    return [
        Finding(
            s,
            None if crit is None else bool(res.w_min <= crit),
            critical_value=float("nan") if crit is None else float(crit),
            warnings=notes + s.warnings,
        )
    ]


def _kruskal_wallis(cell: Cell) -> list[Finding]:
    s = stats.kruskal_wallis(*cell.samples).summary()
    return [Finding(s, below(s.p, cell.alpha), warnings=s.warnings)]


def _dunn(cell: Cell) -> list[Finding]:
    """Dunn's z tests, or MATLAB's ``multcompare`` after ``kruskalwallis`` (``variant: multcompare``:
    the studentized range on mean ranks, df = inf)."""
    multcompare = cell.options.get("variant", "dunn") == "multcompare"
    adjust = str(cell.options.get("p_adjust", "holm"))
    res = stats.dunn(*cell.samples, p_adjust="tukey-kramer" if multcompare else adjust, names=cell.levels)
    out = []
    for pair in res.pairs():
        s = pair.summary
        # Pair rows carry no result warnings (they are the procedure's, about the whole cell).
        out.append(
            Finding(
                s,
                below(s.p_adj, cell.alpha),
                pair=pair_index(cell.levels, pair.group1, pair.group2),
                test="multcompare" if multcompare else "dunn",
                p_adjust="multcompare" if multcompare else adjust,
            )
        )
    return out


def _friedman(cell: Cell) -> list[Finding]:
    s = stats.friedman(*cell.samples).summary()
    return [Finding(s, below(s.p, cell.alpha), warnings=s.warnings)]


SPECS = (
    TestSpec(
        "rank_sum",
        BETWEEN,
        _rank_sum,
        frozenset(),
        2,
        2,
        _ALT | {"method", "continuity"},
        ("rank_biserial",),
        "Wilcoxon rank-sum / Mann-Whitney U (independent samples)",
        each=EACH_PAIR,
    ),
    TestSpec(
        "signed_rank",
        WITHIN,
        _signed_rank,
        frozenset(),
        2,
        2,
        _ALT | {"method", "continuity", "zero_method", "critical_value"},
        ("matched_pairs_r",),
        "Wilcoxon signed-rank (paired by participant); optionally W against the exact W_critical",
        each=EACH_PAIR,
    ),
    TestSpec(
        "kruskal_wallis",
        BETWEEN,
        _kruskal_wallis,
        frozenset({"dunn", "multcompare", "rank_sum"}),
        2,
        None,
        frozenset(),
        ("epsilon_squared",),
        "Kruskal-Wallis H (independent samples)",
    ),
    TestSpec(
        "dunn",
        BETWEEN,
        _dunn,
        frozenset(),
        2,
        None,
        frozenset({"p_adjust", "variant"}),
        ("mean_rank_difference",),
        "Dunn's pairwise rank tests",
        pairwise=True,
    ),
    TestSpec(
        "friedman",
        WITHIN,
        _friedman,
        frozenset({"signed_rank"}),
        2,
        None,
        frozenset(),
        ("kendall_w",),
        "Friedman rank test (repeated measures, complete blocks)",
    ),
)
