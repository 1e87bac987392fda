"""Session engine: clocks, the trial loop, timers, prompts, questionnaires and resume.

Public API
----------
run_session(store, participant_code, *, virtual=True, seed=None, ...) -> SessionResult
    Run an enrolled participant's whole session (virtual participant, scripted person, or a person at
    the terminal). ``studyctl run``, ``studyctl simulate`` and ``studyctl demo`` call it.
resume_session(store, session_id, ...) -> SessionResult
    Continue an interrupted session from its stored plan (``studyctl resume``).
export_study(store, directory, *, samples=True) -> ExportResult
    Tidy CSV files plus a JSON data dictionary (``studyctl export``).
study_progress(store) -> StudyProgress
    Per participant and condition: done, running, left; balance so far (``studyctl status``).
preflight(plan, factory, *, virtual) -> PreflightReport
    Which plugins a session needs and whether each is available.
SessionRunner, MemoryRecorder, StoreRecorder, SessionPlan, plan_for_participant
    The state machine, its recorders and its plan, for embedding and tests.

Heavy modules are imported lazily so ``import studyctl.engine.clock`` stays cheap.
"""

from __future__ import annotations

from typing import Any

_EXPORTS = {
    "run_session": "studyctl.engine.api",
    "resume_session": "studyctl.engine.api",
    "export_study": "studyctl.engine.export",
    "ExportResult": "studyctl.engine.export",
    "study_progress": "studyctl.engine.progress",
    "StudyProgress": "studyctl.engine.progress",
    "preflight": "studyctl.engine.preflight",
    "PreflightReport": "studyctl.engine.preflight",
    "SessionRunner": "studyctl.engine.session",
    "SessionResult": "studyctl.engine.session",
    "MemoryRecorder": "studyctl.engine.recorder",
    "StoreRecorder": "studyctl.engine.store_recorder",
    "SessionPlan": "studyctl.engine.plan",
    "plan_for_participant": "studyctl.engine.planning",
    "RealClock": "studyctl.engine.clock",
    "SimulatedClock": "studyctl.engine.clock",
    "PacedClock": "studyctl.engine.clock",
    "run_trial": "studyctl.engine.trial_loop",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'studyctl.engine' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)
