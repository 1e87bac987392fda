"""A scripted answer the session cannot use leaves it interrupted (resumable) and the one Error line says how."""

from __future__ import annotations

from pathlib import Path

import yaml

from studyctl.cli.app import main
from studyctl.store.enrollment import enroll
from studyctl.store.workspace import init_workspace, open_study

PROTOCOL = Path(__file__).parent / "data" / "pty_protocol.yaml"
TRIALS = {1: [{"t": 2.0, "request": "finish"}], 2: [{"t": 2.5, "request": "finish"}]}


def test_out_of_range_likert_leaves_a_resumable_session(tmp_path, capsys):
    ws = tmp_path / "ws"
    init_workspace(ws, protocol=str(PROTOCOL))
    with open_study(workspace=ws) as o:
        enroll(o.store, code="PTY-AAAAA")
    bad, good = tmp_path / "bad.yaml", tmp_path / "good.yaml"
    bad.write_text(yaml.safe_dump({"likert": {"easy": [9, 5], "prefer_feedback": [4]}, "trials": TRIALS}))
    good.write_text(yaml.safe_dump({"likert": {"easy": [3, 5], "prefer_feedback": [4]}, "trials": TRIALS}))
    assert main(["run", "-p", "PTY-AAAAA", "--input", str(bad), "-w", str(ws)]) != 0
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "`studyctl resume 1`" in errors[0] and "Traceback" not in err
    with open_study(workspace=ws) as o:
        assert o.store.get_session(1).status == "interrupted"
    assert main(["resume", "1", "--input", str(good), "-w", str(ws)]) == 0
    with open_study(workspace=ws) as o:
        assert o.store.get_session(1).status == "completed"
