"""One call from a loaded plan to one result: read the data (database or CSV), run the tests, collect the figures'
data and, for a report, the effect sizes' and model coefficients' intervals.

The plan comes loaded (its name or file is resolved once, by the command or workflow that was given it); the stored
study is opened once, through one :class:`~studyctl.store.reader.StudyReader`, for both its metrics and the figures
drawn from its samples.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from studyctl.analysis.execute import run_plan
from studyctl.analysis.plan import AnalysisPlan, require_loaded
from studyctl.analysis.results import AnalysisResult, FigureData
from studyctl.analysis.table import MetricTable, read_summary_csv
from studyctl.analysis.trials import StoredStudy
from studyctl.errors import AnalysisError, UsageError
from studyctl.store.reader import StudyReader


@contextlib.contextmanager
def open_stored_study(
    plan: AnalysisPlan, *, db: str | None = None, workspace: str | Path | None = None, study: str | None = None
) -> Iterator[StoredStudy]:
    """The plan's study, opened for reading (closed on exit); its protocol must be the plan's.

    The database is ``db`` (a URL or SQLite path), else ``$STUDYCTL_DB``, else the workspace's; the study
    is ``study``, else the workspace's, else the database's only study.
    """
    with StudyReader.open(db, None if workspace is None else str(workspace), study) as reader:
        used = reader.study.protocol_name
        if used and used != plan.study:
            raise AnalysisError(
                f"plan {plan.source_path or plan.title!r} analyses protocol {plan.study!r}, but study "
                f"{reader.study.name!r} ran protocol {used!r}; use that protocol's plan (studyctl analyze {used})"
            )
        yield StoredStudy(reader)


def load_data(
    plan: AnalysisPlan,
    *,
    db: str | None = None,
    workspace: str | Path | None = None,
    study: str | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> MetricTable:
    """The plan's metric table: from its CSV file, or computed from the study database."""
    if plan.data.source == "csv":
        return _csv_table(plan, db)
    from studyctl.analysis.metrics import compute_metrics

    with open_stored_study(plan, db=db, workspace=workspace, study=study) as stored:
        return compute_metrics(plan, stored, on_progress=on_progress)


def _csv_table(plan: AnalysisPlan, db: str | None) -> MetricTable:
    if db is not None:
        raise UsageError(f"plan {plan.source_path} reads its data from {plan.data.path}; --db is not used by it")
    return read_summary_csv(plan.csv_path(), study=plan.study)


def analyze(
    plan: AnalysisPlan,
    *,
    db: str | None = None,
    workspace: str | Path | None = None,
    study: str | None = None,
    table: MetricTable | None = None,
    figures: bool = False,
    intervals: bool = False,
    on_step: Callable[[str], None] | None = None,
    stored: StoredStudy | None = None,
) -> AnalysisResult:
    """Run an analysis plan end to end.

    Parameters
    ----------
    plan
        A loaded plan (:func:`~studyctl.analysis.plan.load_plan` resolves a file or a shipped plan's name).
    db, workspace, study
        Where the study database is (ignored for CSV plans and when ``table`` is given).
    table
        Metric values to analyse instead of reading them (tests, notebooks).
    figures
        Also collect the data of the plan's figures drawn from stored samples or controllers
        (``result.figures``), from the same open study.
    intervals
        Also bootstrap the effect sizes' intervals (:mod:`studyctl.analysis.effect_ci`, ``tables["effect_sizes"]``)
        and fit the model tests' coefficients with Wald intervals (:mod:`studyctl.analysis.model_ci`,
        ``tables["model_coefficients"]``): what a report shows; power and calibration runs leave them out.
    on_step
        Progress callback with the name of each step.
    stored
        The plan's study, already open (:func:`open_stored_study`; the caller closes it), so that a workflow
        reading more of the study opens it once; ``db``, ``workspace`` and ``study`` are then not used.

    Returns
    -------
    AnalysisResult
        ``timings`` has ``metrics_s`` (reading and computing metrics), the runner's own figures and, with
        ``figures``, ``figure_data_s``.
    """
    from studyctl.analysis.figure_data import collect, needs_figure_data

    plan = require_loaded(plan, "analyze")
    want_figures = figures and needs_figure_data(plan)
    figure_data: dict[str, FigureData] = {}
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        if stored is None and plan.data.source == "database" and (table is None or want_figures):
            stored = stack.enter_context(open_stored_study(plan, db=db, workspace=workspace, study=study))
        if table is None:
            if on_step:
                on_step("metrics")
            if stored is None:
                table = _csv_table(plan, db)
            else:
                from studyctl.analysis.metrics import compute_metrics

                table = compute_metrics(plan, stored)
        timings["metrics_s"] = time.perf_counter() - t0
        result = run_plan(plan, table, on_step=on_step)
        timings.update(result.timings)
        if want_figures and stored is not None:
            if on_step:
                on_step("figure data")
            t1 = time.perf_counter()
            figure_data = collect(plan, stored)
            timings["figure_data_s"] = time.perf_counter() - t1
    result = dataclasses.replace(result, timings=timings, figures=figure_data)
    if intervals:
        from studyctl.analysis.effect_ci import effect_size_intervals
        from studyctl.analysis.model_ci import model_coefficient_intervals

        if on_step:
            on_step("effect-size intervals")
        result = dataclasses.replace(result, tables={**result.tables, "effect_sizes": effect_size_intervals(result),
                                                     "model_coefficients": model_coefficient_intervals(result)})
    return result
