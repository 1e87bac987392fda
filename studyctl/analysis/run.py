"""One call from a plan to a result: load the plan, get the data (database or CSV), run the tests."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from studyctl.analysis.execute import run_plan
from studyctl.analysis.plan import AnalysisPlan, load_plan
from studyctl.analysis.results import AnalysisResult
from studyctl.analysis.table import MetricTable, read_summary_csv
from studyctl.errors import AnalysisError, UsageError


def load_data(
    plan: AnalysisPlan,
    *,
    db: str | None = None,
    workspace: str | Path | None = None,
    study: str | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> MetricTable:
    """The plan's metric table: from its CSV file, or computed from the study database.

    The database is ``db`` (a URL or SQLite path), else ``$STUDYCTL_DB``, else the workspace's; the study
    is ``study``, else the workspace's, else the database's only study. Its protocol must be the plan's.
    """
    if plan.data.source == "csv":
        if db is not None:
            raise UsageError(f"plan {plan.source_path} reads its data from {plan.data.path}; --db is not used by it")
        path = plan.csv_path()
        return read_summary_csv(path, study=plan.study)
    from studyctl.analysis.metrics import compute_metrics
    from studyctl.store.workspace import open_study

    with open_study(db, None if workspace is None else str(workspace), study) as opened:
        used = opened.study.protocol_name
        if used and used != plan.study:
            raise AnalysisError(
                f"plan {plan.source_path or plan.title!r} analyses protocol {plan.study!r}, but study "
                f"{opened.study.name!r} ran protocol {used!r}; use that protocol's plan (studyctl analyze {used})"
            )
        return compute_metrics(plan, opened.store, opened.study, on_progress=on_progress)


def analyze(
    plan: AnalysisPlan | str | Path,
    *,
    db: str | None = None,
    workspace: str | Path | None = None,
    study: str | None = None,
    table: MetricTable | None = None,
    on_step: Callable[[str], None] | None = None,
) -> AnalysisResult:
    """Run an analysis plan end to end.

    Parameters
    ----------
    plan
        A plan object, a plan file, or the name of a shipped plan.
    db, workspace
        Where the study database is (ignored for CSV plans and when ``table`` is given).
    table
        Metric values to analyse instead of reading them (tests, notebooks).
    on_step
        Progress callback with the name of each step.

    Returns
    -------
    AnalysisResult
        ``timings`` has ``metrics_s`` (reading and computing metrics) and the runner's own figures.
    """
    if not isinstance(plan, AnalysisPlan):
        plan = load_plan(plan)
    t0 = time.perf_counter()
    if table is None:
        if on_step:
            on_step("metrics")
        table = load_data(plan, db=db, workspace=workspace, study=study)
    metrics_s = time.perf_counter() - t0
    result = run_plan(plan, table, on_step=on_step)
    timings = {"metrics_s": metrics_s, **result.timings}
    return AnalysisResult(
        plan=result.plan,
        data=result.data,
        rows=result.rows,
        tables=result.tables,
        missing=result.missing,
        problems=result.problems,
        timings=timings,
    )
