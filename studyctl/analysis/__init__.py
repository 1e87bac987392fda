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

from __future__ import annotations

import importlib

# Imported on first use (PEP 562): reading and checking a plan (`studyctl analyze PLAN --check`, a hostile plan
# file) must not first import the statistics stack (scipy, statsmodels, pandas and pyarrow: ~100 MB and seconds
# on a loaded machine) only to refuse the file.
_LAZY = {
    "run_plan": "studyctl.analysis.execute",
    "AnalysisPlan": "studyctl.analysis.plan",
    "check_plan": "studyctl.analysis.plan",
    "load_plan": "studyctl.analysis.plan",
    "ROW_COLUMNS": "studyctl.analysis.results",
    "AnalysisResult": "studyctl.analysis.results",
    "TestRow": "studyctl.analysis.results",
    "analyze": "studyctl.analysis.run",
    "load_data": "studyctl.analysis.run",
    "MetricTable": "studyctl.analysis.table",
    "read_summary_csv": "studyctl.analysis.table",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'studyctl.analysis' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


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
