"""A virtual needle operator learns during a session (which cues and guidance to trust); a session resumed in a
new process must go on as the uninterrupted one, so the engine stores that memory with every finished trial."""

from __future__ import annotations

import sqlite3

import pytest

from studyctl.engine.api import resume_session, run_session
from studyctl.engine.recorder import MEMORY_EVENT
from studyctl.errors import SessionInterrupted
from studyctl.store.workspace import open_study
from studyctl.workflows.simulate import create_cohort

pytestmark = pytest.mark.slow  # spawns processes / runs whole sessions: CI runs it, plain pytest skips it

STOP_AFTER_STEPS = 19  # inside the last scenario, after the operator has learnt what to trust in it


def _trials(database: str) -> list[tuple]:
    con = sqlite3.connect(database)
    rows = con.execute(
        "select plan_position, condition, json_extract(outcome, '$.duration_s'), json_extract(outcome, '$.scans') "
        "from trial where status != 'aborted' order by plan_position, id"
    ).fetchall()
    con.close()
    return rows


def test_resumed_virtual_session_goes_on_as_the_uninterrupted_one(tmp_path):
    whole = create_cohort("needle_insertion", 1, 3, tmp_path / "whole")
    split = create_cohort("needle_insertion", 1, 3, tmp_path / "split")
    with open_study(workspace=whole.workspace) as o:
        run_session(o.store, whole.codes[0], virtual=True)
    steps = {"done": 0}

    def crash_after_some_steps(_done, _total, _step) -> None:
        steps["done"] += 1
        if steps["done"] == STOP_AFTER_STEPS:
            raise KeyboardInterrupt

    with open_study(workspace=split.workspace) as o:
        try:
            run_session(o.store, split.codes[0], virtual=True, progress=crash_after_some_steps)
        except SessionInterrupted:
            pass
        else:
            raise AssertionError("the session was not interrupted")
        sid = o.store.list_sessions(o.store.get_participant(o.study.id, split.codes[0]).id)[0].id
        memory = o.store.events_frame(sid)
        memory = memory[memory.kind == MEMORY_EVENT].payload.iloc[-1]["memory"]
        # what a fresh process would forget: something learnt to trust
        assert any(memory["trust_cue"].values()) or any(memory["trust_guide"].values())
        resume_session(o.store, sid)  # a new participant instance, as in a new process
    assert _trials(split.database) == _trials(whole.database)
