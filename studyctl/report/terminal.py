"""Results as terminal tables: what ``studyctl analyze``, ``studyctl power`` and ``studyctl demo`` print.

The CLI only prints these; choosing rows, pivoting and number formatting happen here, beside the report's other
formatting (:mod:`studyctl.report.style`).
"""

from __future__ import annotations

from typing import Any

from rich.markup import escape
from rich.table import Table

from studyctl.report.style import fmt_num, fmt_p


def _row_result(r: Any) -> str:  # a row of AnalysisResult.to_frame()
    if r.kind == "interval":
        return f"{fmt_num(r.estimate)} [{fmt_num(r.ci_low)}, {fmt_num(r.ci_high)}] ({r.n_per_group})"
    if r.test == "newcombe":
        return f"Δp = {fmt_num(r.estimate)}, margin = {fmt_num(r.statistic)}"
    if r.critical_value == r.critical_value:  # not NaN: W against W_critical
        return f"W = {fmt_num(r.statistic)}, W_crit = {fmt_num(r.critical_value)} (n_r = {fmt_num(r.df)})"
    if not r.statistic_name:
        return ""
    df = f", df = {fmt_num(r.df)}" if r.df == r.df else ""
    return f"{r.statistic_name} = {fmt_num(r.statistic)}{df}"


def analysis_tables(result: Any, *, notes_width: int | None = 40) -> list[Table]:
    """One table per test of the plan that produced rows (an :class:`~studyctl.analysis.AnalysisResult`).

    ``notes_width``: notes longer than this end in '…' (a terminal); None keeps them whole (a pipe or file)."""
    frame = result.to_frame()
    tables = []
    for entry in result.plan.tests:
        rows = frame[frame["test_id"] == entry.id]
        if rows.empty:
            continue
        table = Table(title=f"{entry.id}: {entry.title or entry.test}", title_justify="left", box=None, pad_edge=False)
        # The split (e.g. the nodule of a per-nodule interval) gets its own column so blocks are told apart.
        splits = any(rows["split"].astype(bool))
        if splits:
            table.add_column(", ".join(entry.by) or "split", overflow="fold")
        table.add_column("comparison", overflow="fold", min_width=22)
        table.add_column("result", overflow="fold", min_width=30)
        table.add_column("p (adj.)", no_wrap=True)
        table.add_column("sig.", no_wrap=True)
        table.add_column("notes", overflow="ellipsis", no_wrap=True, max_width=notes_width)
        for r in rows.itertuples(index=False):
            what = " ".join(x for x in (r.metric, r.groups) if x)
            if r.kind == "posthoc":
                what = f"  post-hoc {r.groups}"
            split = ", ".join(part.partition("=")[2] for part in r.split.split(", ")) if r.split else ""
            p = fmt_p(r.p) + (f" ({fmt_p(r.p_adj)})" if r.p_adj == r.p_adj else "")
            sig = "" if r.significant is None else ("yes" if r.significant else "no")
            note = ("NOT COMPUTED: " if r.status != "ok" else "") + (r.warnings or "")
            cells = [what, _row_result(r), p, sig, note]
            table.add_row(*(escape(c) for c in ([split, *cells] if splits else cells)))
        tables.append(table)
    return tables


def power_table(run: Any, show_posthoc: bool) -> Table:
    """The power table of a :class:`~studyctl.workflows.power.PowerRun`: one row per test, metric, split and
    levels, one column per sample size (power with its 95 % Wilson interval), the effect size at the largest n."""
    frame = run.to_frame()
    if not show_posthoc:
        frame = frame[frame["kind"] != "posthoc"]
    sizes = list(run.table.sizes)
    table = Table(title="Power (fraction of replicates significant, 95% Wilson interval)", title_justify="left")
    for col in ("test", "metric", "split / levels", *(f"n={n}" for n in sizes), "effect size (median, largest n)"):
        table.add_column(col, overflow="fold")
    keys = list(dict.fromkeys(zip(frame["test_id"], frame["metric"], frame["split"], frame["groups"], strict=True)))
    for key in keys:
        rows = frame[
            (frame["test_id"] == key[0])
            & (frame["metric"] == key[1])
            & (frame["split"] == key[2])
            & (frame["groups"] == key[3])
        ]
        cells = []
        for n in sizes:
            r = rows[rows["participants"] == n]
            if r.empty:
                cells.append("")
                continue
            r = r.iloc[0]
            cells.append(f"{r['power']:.2f} [{r['power_ci_low']:.2f}, {r['power_ci_high']:.2f}]")
        last = rows[rows["participants"] == max(sizes)]
        eff = ""
        if not last.empty and last.iloc[0]["effect_size_name"]:
            eff = f"{last.iloc[0]['effect_size_name']} {fmt_num(last.iloc[0]['effect_median'])}"
        where = " ".join(x for x in (key[2], key[3]) if x)
        table.add_row(key[0], key[1], where, *cells, eff)
    return table


def target_table(target: Any) -> Table:
    """Per test: the smallest size run reaching the target power (a :class:`~studyctl.power.target.TargetTable`)."""
    table = Table(title=f"Smallest sample size reaching power {target.target:g} (among the sizes run; "
                        "95% Wilson interval over the replicates)", title_justify="left")
    for col in ("test", "metric", "split / levels", "participants", "power [95% CI]", "replicates"):
        table.add_column(col, overflow="fold")
    for r in target.to_records():
        where = " ".join(x for x in (r["split"], r["groups"]) if x)
        if r["reached"]:
            n, p = str(r["participants"]), f"{r['power']:.2f} [{r['power_ci_low']:.2f}, {r['power_ci_high']:.2f}]"
        else:
            n, p = f"> {r['largest_run']} (not reached)", f"{r['power_at_largest']:.2f} at n={r['largest_run']}"
        table.add_row(r["test_id"], r["metric"], where, n, p, str(r["replicates"]))
    return table


def demo_table(result: Any) -> Table:
    """The per-study summary of a :class:`~studyctl.workflows.demo.DemoResult`."""
    table = Table(
        title=f"studyctl demo (seed {result.seed}, {result.workers} workers, "
        + (f"1 kHz loops at {result.sim_rate_hz:g} Hz, " if result.sim_rate_hz else "protocol loop rates, ")
        + f"{result.total_s:.1f} s)",
        title_justify="left",
    )
    # sessions: the study's own session run times added up; ready: when its report was written (demo clock)
    for col in ("study", "participants", "trials", "tests", "significant", "sessions", "ready", "status"):
        table.add_column(col)
    for r in result.studies:
        status = "FAILED" if r.error else ("partial" if r.partial else "complete")
        table.add_row(
            r.study, str(r.participants), str(r.trials_completed), str(r.tests), str(r.significant),
            f"{r.simulate_s:.1f} s", f"{r.total_s:.1f} s", status,
        )
    return table


def schedule_text(protocol_id: str, participants: int, seed: int, algorithm_version: Any, rows: Any,
                  balance: Any) -> str:
    """``studyctl protocol schedule``'s table: every participant's planned trials (``rows``, from
    :func:`~studyctl.protocol.schedule_rows`), then per stratum the position and carry-over counts of ``balance``
    (:func:`~studyctl.protocol.schedule_balance`) as condition × position and condition × following condition."""
    lines = [f"{protocol_id}: {participants} participants, seed {seed}, algorithm version {algorithm_version}",
             rows.to_string(index=False)]
    frame = balance.to_frame()
    conditions = list(balance.conditions)
    for stratum in balance.strata:
        pos = frame[(frame.stratum == stratum) & (frame.kind == "position")]
        carry = frame[(frame.stratum == stratum) & (frame.kind == "carryover")]
        lines += [
            f"\nBalance in stratum {stratum}:",
            "position counts (condition × position):",
            pos.pivot(index="condition", columns="other", values="count").reindex(conditions).to_string(),
            "carry-over counts (row followed by column):",
            carry.pivot(index="condition", columns="other", values="count")
            .reindex(index=conditions, columns=conditions).fillna(0).astype(int).to_string(),
        ]
    lines += ["\n" + balance.summary_frame().to_string(index=False),
              "(spread = max − min count over the counterbalanced conditions; 0 is perfectly balanced)"]
    return "\n".join(lines)


def bench_tables(result: Any) -> list[Table]:
    """A :class:`~studyctl.bench.BenchResult`'s figures beside their peers measured in the same run, then each of
    its own tables (``studyctl bench NAME``)."""
    table = Table(title=f"studyctl bench {result.name}")
    table.add_column("figure")
    table.add_column("value", justify="right")
    table.add_column("peer (same run)", justify="right")
    for key, value in result.figures.items():
        peer = result.peers.get(key)
        table.add_row(key, f"{value:.4g}", "" if peer is None else f"{peer:.4g}")
    for key, value in result.peers.items():
        if key not in result.figures:
            table.add_row(key, "", f"{value:.4g}")
    tables = [table]
    for title, rows in result.tables.items():
        if not rows:
            continue
        sub = Table(title=title)
        for col in rows[0]:
            sub.add_column(str(col))
        for row in rows:
            sub.add_row(*(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row.values()))
        tables.append(sub)
    return tables


def plugins_table(frame: Any, *, wide: bool) -> Table:
    """``studyctl plugins list``: one row a plugin (``PluginListing.to_frame()``), a broken one in red. ``wide``: the
    failures' reasons in a last column (a narrow terminal gets them after the table instead)."""
    table = Table(title="studyctl plugins")
    for col in ("kind", "name", "package", "version", "status"):
        table.add_column(col, no_wrap=True)
    if wide:
        table.add_column("detail", overflow="fold")
    for row in frame.itertuples(index=False):
        style = None if row.status == "ok" else "red"
        cells = [row.kind, row.name, row.package, row.version, row.status]
        table.add_row(*cells, *([row.detail] if wide else []), style=style)
    return table


def frame_table(title: str, frame: Any) -> Table:
    """Every column and row of a small frame as it is (``studyctl device list``)."""
    table = Table(title=title)
    for col in frame.columns:
        table.add_column(col, overflow="fold")
    for row in frame.itertuples(index=False):
        table.add_row(*(str(v) for v in row))
    return table


def safety_table(checks: Any) -> Table:
    """``studyctl device check``: each safety rule exercised on the device, passed or not, and what was seen."""
    table = Table(title="safety layer on the device")
    for col in ("rule", "passed", "detail"):
        table.add_column(col, overflow="fold")
    for c in checks:
        table.add_row(c.rule, "yes" if c.passed else "NO", c.detail)
    return table
