"""Engine test helpers: make the toy plugins in this folder importable (importlib import mode); a study with one
scripted person session."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture
def scripted_person_study(tmp_path):
    """The terminal test study (``data/pty_protocol.yaml``) with PTY-AAAAA's person session run to its end from a
    script of answers; the workspace folder."""
    import yaml

    from studyctl.engine.api import run_session
    from studyctl.store.enrollment import enroll
    from studyctl.store.workspace import init_workspace, open_study

    script = {"likert": {"easy": [4, 5], "prefer_feedback": [4]},
              "trials": {1: [{"t": 2.0, "request": "finish"}], 2: [{"t": 2.5, "request": "finish"}]}}
    ws = tmp_path / "ws"
    init_workspace(ws, protocol=str(Path(__file__).parent / "data" / "pty_protocol.yaml"))
    answers = tmp_path / "answers.yaml"
    answers.write_text(yaml.safe_dump(script))
    with open_study(workspace=ws) as o:
        enroll(o.store, code="PTY-AAAAA")
        run_session(o.store, "PTY-AAAAA", virtual=False, script=answers)
    return ws
