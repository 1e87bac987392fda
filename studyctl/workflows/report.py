"""Loaded plan → one analysis result → report folder, in one call (what ``studyctl report`` runs)."""

from __future__ import annotations

import contextlib
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from studyctl.analysis.plan import AnalysisPlan, require_loaded
from studyctl.analysis.results import AnalysisResult
from studyctl.analysis.run import analyze, open_stored_study
from studyctl.report.build import ReportFiles, check_figure_formats, ensure_writable, write_report
from studyctl.workflows.agreement import with_agreement


@dataclass(frozen=True)
class ReportRun:
    """The analysis result, the files written, and how long each stage took."""

    result: AnalysisResult
    files: ReportFiles
    timings: dict[str, float]


def build_report(
    plan: AnalysisPlan,
    out_dir: str | Path,
    *,
    db: str | None = None,
    workspace: str | Path | None = None,
    study: str | None = None,
    on_step: Callable[[str], None] | None = None,
    targets: str | Path | None = None,
    figure_formats: tuple[str, ...] = ("png", "svg", "pdf"),
    effect_size_ci: bool = True,
) -> ReportRun:
    """Analyse ``plan`` (database or CSV data; loaded by the caller) and write its report into ``out_dir``.

    The output folder is checked for writability before anything is computed. The study is opened once, here, for
    the tests, the figures' data and the comparison with the paper; the analysis returns one result and the report
    is written from it alone. A simulated study's report gets a "simulated vs published" section and
    ``agreement.csv`` (``targets``: a targets file; default: the protocol's shipped one). ``effect_size_ci``:
    bootstrap intervals of the effect sizes (``effect_sizes.csv``) and the model tests' coefficients with Wald
    intervals (``model_coefficients.csv``).
    """
    plan = require_loaded(plan, "build_report")
    created = not Path(out_dir).exists()
    ensure_writable(out_dir)
    try:
        check_figure_formats(figure_formats)
        t0 = time.perf_counter()
        with contextlib.ExitStack() as stack:
            stored = None
            if plan.data.source == "database":  # opened once: the tests, the figures' data and the comparison
                stored = stack.enter_context(open_stored_study(plan, db=db, workspace=workspace, study=study))
            result = analyze(plan, db=db, figures=True, intervals=effect_size_ci, on_step=on_step, stored=stored)
            if stored is not None:  # a simulated study: its report compares it with the paper
                result = with_agreement(result, stored.reader, targets=targets)
        t2 = time.perf_counter()
        files = write_report(result, out_dir, on_step=on_step, figure_formats=figure_formats)
        t3 = time.perf_counter()
    except BaseException:
        # A mistake (a plan that is not YAML, no study) leaves no empty or half-written report folder behind.
        if created:
            shutil.rmtree(out_dir, ignore_errors=True)
        raise
    figure_data_s = result.timings.get("figure_data_s", 0.0)
    timings = {
        "analyze_s": t2 - t0 - figure_data_s,
        "figure_data_s": figure_data_s,
        "report_s": t3 - t2,
        "total_s": t3 - t0,
    }
    return ReportRun(result=result, files=files, timings=timings)
