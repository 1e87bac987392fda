"""run_session / resume_session / export / status / preflight through the real plugins and the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from studyctl.cli.app import main
from studyctl.engine.api import run_session
from studyctl.engine.export import export_study
from studyctl.engine.factory import EntryPointFactory, MappingFactory
from studyctl.engine.planning import plan_for_participant
from studyctl.engine.preflight import preflight
from studyctl.engine.progress import study_progress
from studyctl.errors import NotFoundError, SessionError, UsageError
from studyctl.protocol import Schedule
from studyctl.store.enrollment import enroll, study_protocol
from studyctl.store.workspace import init_workspace, open_study

PROTOCOL = Path(__file__).parent / "data" / "pty_protocol.yaml"


@pytest.fixture
def ws(tmp_path):
    folder = tmp_path / "ws"
    init_workspace(folder, protocol=str(PROTOCOL))
    with open_study(workspace=folder) as o:
        enroll(o.store, code="PTY-AAAAA")
        enroll(o.store, code="PTY-BBBBB")
    return folder


SCRIPT = {
    "likert": {"easy": [9, "x", 5, 2], "prefer_feedback": [4]},
    "trials": {
        1: [{"t": 1.0, "request": "report", "answer": "8 1"}, {"t": 2.0, "request": "report", "answer": "3 4"},
            {"t": 5.0, "request": "finish"}],
        2: [{"t": 2.5, "request": "finish"}],
    },
}


def test_scripted_person_run_via_cli_then_export_and_status(ws, tmp_path, capsys):
    answers = tmp_path / "answers.yaml"
    answers.write_text(yaml.safe_dump(SCRIPT))
    code = main(["run", "--participant", "PTY-AAAAA", "--input", str(answers), "--workspace", str(ws)])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "Session 1 (PTY-AAAAA): completed; 2 trials completed, 0 aborted, 0 invalid, 3 answers" in out.out
    # invalid scripted answers are reported with the reason and asked again
    assert "item easy: 9 is not on the scale; type one of 1, 2, 3, 4, 5; asking again" in out.err
    assert "item easy: 'x' is not a number; type one of 1, 2, 3, 4, 5; asking again" in out.err
    assert "report '8 1' at t=1.0: column '8' is not on the grid" in out.err

    with open_study(workspace=ws) as o:
        trials = o.store.list_trials()
        assert [(t.status, t.outcome["ended_by"]) for t in trials] == [("completed", "finish")] * 2
        assert trials[0].outcome["duration_s"] == pytest.approx(5.0)
        assert [r.payload for r in o.store.location_reports(trials[0].id)] == [{"column": "3", "row": "4"}]
        progress = study_progress(o.store)
        rows = {(r.participant, r.condition): r for r in progress.rows}
        assert all(rows[("PTY-AAAAA", c)].done == 1 and rows[("PTY-AAAAA", c)].left == 0 for c in ("none", "linear"))
        assert all(rows[("PTY-BBBBB", c)].done == 0 and rows[("PTY-BBBBB", c)].left == 1 for c in ("none", "linear"))
        assert sum(progress.first_condition["all"].values()) == 2

        result = export_study(o.store, tmp_path / "export")
        with pytest.raises(UsageError, match="not an empty folder"):
            export_study(o.store, tmp_path / "export")
    files = {p.name for p in (tmp_path / "export").iterdir()}
    assert files == {"trials.csv", "events.csv", "responses.csv", "reports.csv", "samples_linear.csv",
                     "samples_none.csv", "records.csv", "datapackage.json", "data_dictionary.json"}
    dictionary = json.loads((tmp_path / "export" / "data_dictionary.json").read_text())
    import pandas as pd

    for name, cols in dictionary["files"].items():
        frame = pd.read_csv(tmp_path / "export" / name)
        assert list(frame.columns) == list(cols), name  # every column described, in order
        assert all(c["description"] and "unit" in c for c in cols.values())
    samples = pd.concat([pd.read_csv(tmp_path / "export" / f"samples_{c}.csv") for c in ("none", "linear")])
    assert len(samples) == result.rows["samples_none.csv"] + result.rows["samples_linear.csv"] \
        == sum(t.outcome["ticks"] for t in trials)
    units = {k: v["unit"] for k, v in dictionary["files"]["samples_linear.csv"].items()}
    assert units["t"] == "s" and any(u == "N" for k, u in units.items() if k.endswith("_n"))
    responses = pd.read_csv(tmp_path / "export" / "responses.csv")
    assert list(responses.code) == [5, 2, 4]
    assert list(responses.label.astype(object).where(responses.label.notna(), "")) == ["Strongly agree", "", ""]
    assert set(responses.instrument_version.astype(str)) == {"1.0"}

    status = main(["status", "--workspace", str(ws)])
    text = capsys.readouterr().out
    assert status == 0
    assert "PTY-AAAAA" in text and "session 1 completed" in text and "left 0" in text
    assert "PTY-BBBBB" in text and "no session" in text and "left 2" in text
    assert "balance [all]: first condition:" in text


def test_bad_input_gets_one_clear_line(ws, tmp_path, capsys):
    assert main(["run", "--participant", "NOPE", "--virtual", "--workspace", str(ws)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("Error: no participant with code 'NOPE' in study 'engine_pty_test'; enrolled codes: ")
    assert "Traceback" not in err
    # the protocol's virtual participant cannot answer the questionnaires: preflight says so, nothing is written
    assert main(["run", "--participant", "PTY-AAAAA", "--virtual", "--workspace", str(ws)]) == 1
    err = capsys.readouterr().err
    assert "preflight failed" in err and "virtual_palpator" in err and "cannot answer questionnaires" in err
    with open_study(workspace=ws) as o:
        assert o.store.list_sessions(o.store.get_participant(o.study.id, "PTY-AAAAA").id) == []
    assert main(["resume", "99", "--workspace", str(ws)]) == 1
    assert capsys.readouterr().err.startswith("Error: no session with id 99")
    for speed in ("0", "-2", "nan"):  # a bad option value is a usage error (exit 2), and nothing is written
        assert main(["run", "--participant", "PTY-BBBBB", "--virtual", "--speed", speed, "--workspace", str(ws)]) == 2
        assert "--speed must be a positive number" in capsys.readouterr().err
    with open_study(workspace=ws) as o:
        assert o.store.list_sessions(o.store.get_participant(o.study.id, "PTY-BBBBB").id) == []
    bad = tmp_path / "bad.yaml"
    bad.write_text("likert: {easy: [3]}\nanswers: 1\n")
    assert main(["run", "--participant", "PTY-AAAAA", "--input", str(bad), "--workspace", str(ws)]) == 2
    assert "unknown key(s) ['answers']" in capsys.readouterr().err
    answers = tmp_path / "answers.yaml"
    answers.write_text(yaml.safe_dump(SCRIPT))
    assert main(["run", "--participant", "PTY-AAAAA", "--input", str(answers), "--workspace", str(ws)]) == 0
    capsys.readouterr()
    assert main(["run", "--participant", "PTY-AAAAA", "--input", str(answers), "--workspace", str(ws)]) == 1
    assert "already completed session 1" in capsys.readouterr().err
    assert main(["resume", "1", "--workspace", str(ws)]) == 1
    assert "session 1 is already complete" in capsys.readouterr().err


def test_preflight_names_what_is_missing(ws):
    with open_study(workspace=ws) as o:
        person = o.store.get_participant(o.study.id, "PTY-AAAAA")
        plan = plan_for_participant(study_protocol(o.study), Schedule.from_json(person.schedule))
        full = preflight(plan, EntryPointFactory(), virtual=False)
        assert full.ok, full.to_frame()
        assert set(full.to_frame().kind) == {"scene", "controller", "device", "participant"}
        partial = MappingFactory({"scene": {"sponge_phantom": object}, "device": {"sim_palpation": object},
                                  "controller": {"none": object}, "participant": {"person": object}})
        report = preflight(plan, partial, virtual=False)
        assert [(c.kind, c.name) for c in report.missing] == [("controller", "linear")]
        with pytest.raises(SessionError, match=r"preflight failed, 1 plugin\(s\) not available: controller "
                                               r"'linear' \(needed by condition linear\): no controller plugin"):
            run_session(o.store, "PTY-AAAAA", virtual=False, factory=partial, script=None,
                        ui=object(), participant=object())
        assert o.store.list_sessions(person.id) == []
        with pytest.raises(NotFoundError):
            run_session(o.store, "PTY-ZZZZZ")


@pytest.mark.slow
def test_manual_condition_outcome_entered_by_the_coordinator(tmp_path, capsys):
    """Seed 002: in the manual condition no controller runs; the coordinator enters time and locations."""
    folder = tmp_path / "ddp"
    init_workspace(folder, protocol="data_driven_palpation")
    with open_study(workspace=folder) as o:
        e = enroll(o.store, code="DDP-AAAAA")
        order = e.schedule.order
    manual_trial = order.index("manual") + 1
    haptic_trial = order.index("haptic") + 1
    script = {
        "outcomes": [{"duration_s": 29.5, "reports": ["40 60", "500 1", "80 30"], "note": "cloth slipped once"}],
        "trials": {haptic_trial: [{"t": 1.5, "request": "report", "answer": "70 20"},
                                  {"t": 3.0, "request": "finish"}]},
    }
    answers = tmp_path / "answers.json"
    answers.write_text(json.dumps(script))
    assert main(["run", "--participant", "DDP-AAAAA", "--input", str(answers), "--workspace", str(folder)]) == 0
    err = capsys.readouterr().err
    assert "report: (500, 1) mm is outside the tissue (x 0–120, y 0–120); asking again" in err
    with open_study(workspace=folder) as o:
        trials = {t.plan_position: t for t in o.store.list_trials()}
        manual = trials[manual_trial]
        assert manual.condition == "manual" and manual.status == "completed"
        assert manual.outcome["duration_s"] == pytest.approx(29.5) and manual.outcome["ticks"] == 0
        assert [r.payload for r in o.store.location_reports(manual.id)] == [
            {"x_mm": 40.0, "y_mm": 60.0}, {"x_mm": 80.0, "y_mm": 30.0}]
        assert o.store.read_samples(manual.id).empty  # nothing ran: no samples
        events = o.store.events_frame(1, trial_id=manual.id)
        assert events[events.kind == "manual_outcome"].payload.iloc[0]["note"] == "cloth slipped once"
        haptic = trials[haptic_trial]
        assert haptic.outcome["ended_by"] == "finish" and haptic.outcome["rate_hz"] == 1000.0
        assert [r.payload for r in o.store.location_reports(haptic.id)] == [{"x_mm": 70.0, "y_mm": 20.0}]


def test_resume_refuses_a_session_another_live_process_runs(ws, tmp_path):
    import socket
    import subprocess
    import sys

    from studyctl.engine.api import resume_session
    from studyctl.store.models import SessionLease, utcnow

    answers = tmp_path / "answers.yaml"
    answers.write_text(yaml.safe_dump(SCRIPT))
    with open_study(workspace=ws) as o:
        run_session(o.store, "PTY-AAAAA", virtual=False, script=answers)
        # pretend session 1 is unfinished and its lease held by a live process on this machine
        o.store.update_session(1, status="running")
        sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
        try:
            with o.store.in_transaction() as tx:
                tx.add(SessionLease(session_id=1, token="x" * 32, pid=sleeper.pid, host=socket.gethostname(),
                                    acquired_at=utcnow(), heartbeat_at=utcnow()))
            expected = (f"session 1 is being run by pid {sleeper.pid} on {socket.gethostname()} since .*; if that "
                        "process is gone, studyctl resume 1 --take-over")
            with pytest.raises(SessionError, match=expected):
                resume_session(o.store, 1, script=answers)
            with pytest.raises(SessionError, match=expected):  # a live owner on this machine: no take-over
                resume_session(o.store, 1, script=answers, take_over=True)
        finally:
            sleeper.kill()
            sleeper.wait()
        # the owner is gone: a plain resume names the lease left behind and --take-over; nothing is written
        audited = len(o.store.audit_frame())
        with pytest.raises(SessionError, match=rf"session 1 is still held by pid {sleeper.pid} on .* which is gone "
                                               r"\(no process \d+ runs on this machine.*studyctl resume 1 "
                                               r"--take-over$"):
            resume_session(o.store, 1, script=answers)
        assert len(o.store.audit_frame()) == audited
        # a second `run` of the participant points at the same fix
        with pytest.raises(SessionError, match=r"unfinished session 1 \(running\); continue it with `studyctl resume "
                                               r"1 --take-over`"):
            run_session(o.store, "PTY-AAAAA", virtual=False, script=answers)
        # --take-over takes it, audited
        result = resume_session(o.store, 1, script=answers, take_over=True)
        assert result.status == "completed"
        actions = list(o.store.audit_frame()["action"])
        assert "session.take_over" in actions
        assert o.store.verify_audit().ok
