"""``studyctl analyze``, ``studyctl report``, ``studyctl simulate`` and ``studyctl demo``."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from studyctl.cli.common import DB_OPTION, STUDY_OPTION, WORKSPACE_OPTION, workspace_arg


def _console(err: bool = False) -> Console:
    return Console(stderr=err, highlight=False)


def _print_result(result, console: Console) -> None:  # noqa: ANN001 - AnalysisResult, imported lazily
    from studyctl.report.style import fmt_num, fmt_p

    frame = result.to_frame()
    for entry in result.plan.tests:
        rows = frame[frame["test_id"] == entry.id]
        if rows.empty:
            continue
        table = Table(title=f"{entry.id}: {entry.title or entry.test}", title_justify="left", show_lines=False)
        for col in ("metric", "split", "groups", "n", "statistic", "p", "p adj.", "sig.", "notes"):
            table.add_column(col, overflow="fold")
        for r in rows.itertuples(index=False):
            stat = f"{r.statistic_name} = {fmt_num(r.statistic)}" if r.statistic_name else ""
            if r.kind == "interval":
                stat = f"{fmt_num(r.estimate)} [{fmt_num(r.ci_low)}, {fmt_num(r.ci_high)}]"
            sig = "" if r.significant is None else ("yes" if r.significant else "no")
            note = ("NOT COMPUTED: " if r.status != "ok" else "") + (r.warnings or "")
            table.add_row(
                r.metric,
                r.split,
                r.groups,
                str(r.n),
                stat,
                fmt_p(r.p),
                fmt_p(r.p_adj) if r.p_adj == r.p_adj else "",
                sig,
                note[:120],
            )
        console.print(table)


def register(app: typer.Typer) -> None:
    @app.command("analyze")
    def analyze(
        plan: str = typer.Argument(..., help="Analysis plan file, or a shipped plan name (e.g. needle_insertion)."),
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
        as_json: bool = typer.Option(False, "--json", help="Print the tests table as JSON records."),
        check: bool = typer.Option(False, "--check", help="Only validate the plan (every problem, file:line)."),
    ) -> None:
        """Run an analysis plan on a study database (or its summary CSV) and print the tests table."""
        from studyctl.analysis import analyze as run_analysis
        from studyctl.analysis import load_plan

        loaded = load_plan(plan)
        if check:
            typer.echo(
                f"{loaded.source_path}: OK ({len(loaded.metrics)} metrics, {len(loaded.tests)} tests, "
                f"{len(loaded.figures)} figures)"
            )
            return
        result = run_analysis(loaded, db=db, workspace=workspace_arg(workspace), study=study)
        if as_json:
            typer.echo(result.to_frame().to_json(orient="records"))
        else:
            _print_result(result, _console())
        if result.partial:
            err = _console(err=True)
            err.print("[bold yellow]PARTIAL RESULTS[/]: some of what the plan asks for could not be computed:")
            for p in result.problems:
                err.print(f"  - {p}", markup=False)

    @app.command("report")
    def report(
        plan: str = typer.Argument(..., help="Analysis plan file, or a shipped plan name."),
        out: Path = typer.Option(..., "--out", "-o", help="Folder for tables, figures, report.html and report.md."),
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
    ) -> None:
        """Analyse a plan and write tidy CSV tables, figures, an HTML report and Markdown into a folder."""
        from studyctl.report.pipeline import build_report

        console = _console()
        with console.status("analysing…") as status:
            run = build_report(
                plan,
                out,
                db=db,
                workspace=workspace_arg(workspace),
                study=study,
                on_step=lambda s: status.update(f"{s}…"),
            )
        files = run.files
        console.print(f"Report: {files.html}", markup=False)
        console.print(
            f"        {files.markdown}  ({len(files.tables)} tables, {len(files.figures)} figures)", markup=False
        )
        if files.partial:
            err = _console(err=True)
            err.print("[bold yellow]PARTIAL RESULTS[/] (also marked in the report):")
            for p in files.problems:
                err.print(f"  - {p}", markup=False)

    _ = json  # reserved for --json outputs of simulate/demo
