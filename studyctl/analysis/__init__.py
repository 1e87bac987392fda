"""Analysis: plans (strict YAML), metrics from the study store or a summary CSV, tests, tidy results.

Public API:

* :func:`load_plan`, :func:`check_plan`, :class:`AnalysisPlan` — the plan language.
* :func:`analyze` — plan → :class:`AnalysisResult` (database or CSV data); :func:`load_data`.
* :func:`run_plan` — execute a plan on a :class:`MetricTable` you already have.
* :func:`compute_metrics` — the plan's metrics from a stored study (a :class:`studyctl.store.StudyReader`
  or an open store); :func:`read_summary_csv`.
* ``studyctl.analysis.procedures`` — the tests as a registry (one ``TestSpec`` per test).
* :class:`AnalysisResult` (``to_frame()`` with :data:`ROW_COLUMNS`), :class:`TestRow`, :class:`MetricTable`.
"""

from studyctl.analysis.execute import run_plan
from studyctl.analysis.plan import AnalysisPlan, check_plan, load_plan
from studyctl.analysis.results import ROW_COLUMNS, AnalysisResult, TestRow
from studyctl.analysis.run import analyze, load_data
from studyctl.analysis.table import MetricTable, read_summary_csv


def compute_metrics(*args, **kwargs):  # noqa: D103 - documented in studyctl.analysis.metrics
    from studyctl.analysis.metrics import compute_metrics as _compute

    return _compute(*args, **kwargs)


compute_metrics.__doc__ = "Compute a plan's metrics from a stored study; see :mod:`studyctl.analysis.metrics`."

__all__ = [
    "ROW_COLUMNS",
    "AnalysisPlan",
    "AnalysisResult",
    "MetricTable",
    "TestRow",
    "analyze",
    "check_plan",
    "compute_metrics",
    "load_data",
    "load_plan",
    "read_summary_csv",
    "run_plan",
]
