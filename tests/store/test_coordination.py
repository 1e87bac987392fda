"""consent, withdraw, note and the enrollment target: audited, in the export, bad input refused whole."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
import yaml

from studyctl.cli.app import main
from studyctl.engine.api import run_session
from studyctl.store.enrollment import enroll
from studyctl.store.workspace import init_workspace, open_study

PROTOCOL = Path(__file__).parents[1] / "engine" / "data" / "pty_protocol.yaml"
SCRIPT = {"likert": {"easy": [4, 5], "prefer_feedback": [4]},
          "trials": {1: [{"t": 2.0, "request": "finish"}], 2: [{"t": 2.5, "request": "finish"}]}}


def _workspace(tmp_path: Path, *, consent: str | None = "2.1", target: int | None = 2) -> Path:
    text = PROTOCOL.read_text()
    if consent:
        text = text.replace('  seed: 11\n', f'  seed: 11\n  consent_version: "{consent}"\n')
    if target:
        text = text.replace("  code_prefix: PTY\n", f"  code_prefix: PTY\n  target_n: {target}\n")
    proto = tmp_path / "p.yaml"
    proto.write_text(text)
    ws = tmp_path / "ws"
    init_workspace(ws, protocol=str(proto))
    return ws


def _audit_rows(ws: Path) -> int:
    with open_study(workspace=ws) as o:
        return len(o.store.audit_frame())


def _cli(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_consent_note_withdraw_recorded_audited_and_exported(tmp_path, capsys):
    ws = _workspace(tmp_path)
    answers = tmp_path / "answers.yaml"
    answers.write_text(yaml.safe_dump(SCRIPT))
    with open_study(workspace=ws) as o:
        enroll(o.store, code="PTY-AAAAA")
        enroll(o.store, code="PTY-BBBBB")
        result = run_session(o.store, "PTY-AAAAA", virtual=False, script=answers)
        trial_id = o.store.list_trials(session_id=result.session_id)[0].id
    w = ("-w", str(ws))
    assert _cli(capsys, "consent", "PTY-AAAAA", "--version", "2.1", *w)[0] == 0
    code, out, _ = _cli(capsys, "note", "participant sneezed at 30 s", "--trial", str(trial_id), *w)
    assert code == 0 and f"trial {trial_id}" in out
    assert _cli(capsys, "note", "room too warm", "--session", str(result.session_id), *w)[0] == 0
    code, out, _ = _cli(capsys, "withdraw", "PTY-BBBBB", "--reason", "no longer available", *w)
    assert code == 0 and "Withdrew PTY-BBBBB: 0 trials done kept, 2 planned trials dropped" in out

    with open_study(workspace=ws) as o:
        assert o.store.verify_audit().ok
        actions = list(o.store.audit_frame().action)
        assert {"participant.consent", "note", "participant.status"} <= set(actions)
        assert o.store.get_participant(o.study.id, "PTY-BBBBB").status == "withdrawn"
    # withdrawn: no sessions; the freed place lets one more enroll under the target of 2
    code, _, err = _cli(capsys, "run", "--participant", "PTY-BBBBB", "--input", str(answers), *w)
    assert code != 0 and "withdrawn" in err
    assert _cli(capsys, "enroll", "--code", "PTY-CCCCC", *w)[0] == 0

    out_dir = tmp_path / "export"
    assert main(["export", str(out_dir), "-w", str(ws), "--no-samples"]) == 0
    records = pd.read_csv(out_dir / "records.csv")
    assert list(records.record) == ["consent", "note", "note", "withdrawal"]
    assert records.consent_version.dropna().astype(str).tolist() == ["2.1"]
    assert records.loc[records.record == "note", "trial_id"].dropna().astype(int).tolist() == [trial_id]
    assert records.loc[records.record == "withdrawal", "text"].tolist() == ["no longer available"]


@pytest.mark.slow
def test_bad_input_is_one_error_line_and_writes_nothing(tmp_path, capsys):
    ws = _workspace(tmp_path)
    with open_study(workspace=ws) as o:
        enroll(o.store, code="PTY-AAAAA")
        enroll(o.store, code="PTY-BBBBB")
    w = ("-w", str(ws))
    assert _cli(capsys, "withdraw", "PTY-BBBBB", "--reason", "moved away", *w)[0] == 0
    before = _audit_rows(ws)
    cases = [
        (("withdraw", "PTY-AAAAX", "--reason", "x"), "did you mean 'PTY-AAAAA'"),
        (("withdraw", "PTY-BBBBB", "--reason", "again"), "already withdrew"),
        (("withdraw", "PTY-AAAAA", "--reason", "  "), "reason is empty"),
        (("withdraw", "PTY-BBBBB", "--reason", "x", "--delete-data"), "nothing recorded of them is left to erase"),
        (("note", "hello", "--trial", "999"), "no trial 999"),
        (("note", "hello", "--session", "999"), "no session 999"),
        (("consent", "PTY-AAAAA", "--version", "2.0"), "does not match the protocol's consent_version '2.1'"),
        (("consent", "PTY-BBBBB", "--version", "2.1"), "has withdrawn"),
        (("enroll", "--code", "PTY-CCCCC"), None),  # one place left (B withdrew): allowed
        (("enroll", "--code", "PTY-DDDDD"), "reached its target of 2 participants"),
    ]
    for args, message in cases:
        code, _, err = _cli(capsys, *args, *w)
        if message is None:
            assert code == 0, err
            before = _audit_rows(ws)
            continue
        lines = [x for x in err.splitlines() if x.strip()]
        assert code != 0 and len(lines) == 1 and lines[0].startswith("Error:") and message in lines[0], (args, err)
        assert _audit_rows(ws) == before, args  # nothing written
    code, out, _ = _cli(capsys, "enroll", "--code", "PTY-DDDDD", "--over-target", *w)
    assert code == 0 and ("over the target: the study has reached its target of 2 participants (2 enrolled, not "
                          "withdrawn); enrolled on purpose (--over-target), recorded") in out
    # on purpose, but not silently: audited in the same transaction and in the export's records
    assert _audit_rows(ws) == before + 2
    out_dir = tmp_path / "export"
    assert main(["export", str(out_dir), "-w", str(ws), "--no-samples"]) == 0
    records = pd.read_csv(out_dir / "records.csv")
    assert records.record.tolist() == ["withdrawal", "over_target"]
    assert records.participant.tolist() == ["PTY-BBBBB", "PTY-DDDDD"]
    assert "target of 2 participants" in records.text.iloc[1]
    capsys.readouterr()
    code, out, _ = _cli(capsys, "enroll", "--code", "PTY-EEEEE", "--over-target", "--json", *w)
    assert code == 0 and "target of 2" in json.loads(out)["over_target"]
    with open_study(workspace=ws) as o:
        assert o.store.verify_audit().ok


def test_consent_without_a_declared_version_takes_any(tmp_path, capsys):
    ws = _workspace(tmp_path, consent=None, target=None)
    with open_study(workspace=ws) as o:
        enroll(o.store, code="PTY-AAAAA")
    code, out, _ = _cli(capsys, "consent", "PTY-AAAAA", "--version", "local-3", "--json", "-w", str(ws))
    assert code == 0 and '"version": "local-3"' in out


@pytest.mark.slow
def test_a_note_typed_during_a_trial_is_a_record(tmp_path):
    """The run prompt's `n` (here the scripted equivalent): the trial goes on, the note is in the export."""
    ws = _workspace(tmp_path, consent=None, target=None)
    answers = tmp_path / "answers.yaml"
    answers.write_text(yaml.safe_dump({**SCRIPT, "controls": [{"trial": 1, "t": 1.0, "action": "note",
                                                               "reason": "probe re-seated"}]}))
    with open_study(workspace=ws) as o:
        enroll(o.store, code="PTY-AAAAA")
        result = run_session(o.store, "PTY-AAAAA", virtual=False, script=answers)
        assert result.status == "completed" and result.trials_completed == 2  # the note stopped nothing
        first = min(t.id for t in o.store.list_trials(session_id=result.session_id) if t.status == "completed")
        assert o.store.verify_audit().ok
        events = o.store.events_frame(result.session_id)
        assert events[events.kind == "coordinator_note"].payload.tolist() == [{"text": "probe re-seated"}]
    out_dir = tmp_path / "export"
    assert main(["export", str(out_dir), "-w", str(ws), "--no-samples"]) == 0
    records = pd.read_csv(out_dir / "records.csv")
    assert records.record.tolist() == ["note"] and records.text.tolist() == ["probe re-seated"]
    assert records.trial_id.astype(int).tolist() == [first]
    assert main(["audit", "verify", "-w", str(ws)]) == 0


@pytest.mark.slow
def test_status_counts_dropped_samples_and_missing_data(tmp_path, capsys):
    """Dropped samples (loop ticks without a stored row), trials and answers missing once a session has ended."""
    import sqlite3

    from studyctl.engine.data_gaps import data_gaps

    ws = _workspace(tmp_path, consent=None, target=None)
    answers = tmp_path / "answers.yaml"
    answers.write_text(yaml.safe_dump(SCRIPT))
    with open_study(workspace=ws) as o:
        enroll(o.store, code="PTY-AAAAA")
        enroll(o.store, code="PTY-BBBBB")
        enroll(o.store, code="PTY-CCCCC")
        result = run_session(o.store, "PTY-AAAAA", virtual=False, script=answers)
        assert result.status == "completed"
        clean = data_gaps(o.store).totals()
    # every loop tick of both trials is a stored sample row; nobody is missing anything yet (B, C not started)
    assert clean["trials_checked"] == 2 and clean["ticks"] == clean["samples_stored"] > 100
    assert (clean["dropped_samples"], clean["trials_missing"], clean["answers_missing"]) == (0, 0, 0)
    w = ("-w", str(ws))
    assert _cli(capsys, "withdraw", "PTY-BBBBB", "--reason", "moved away", *w)[0] == 0
    # 37 rows that never reached the store, one answer lost: edited behind studyctl's back to make the gaps
    con = sqlite3.connect(ws / "study.db")
    trial_id, outcome = con.execute("SELECT id, outcome FROM trial WHERE status = 'completed' ORDER BY id").fetchone()
    outcome = json.loads(outcome)
    con.execute("UPDATE trial SET outcome = ? WHERE id = ?",
                (json.dumps({**outcome, "ticks": outcome["ticks"] + 37}), trial_id))
    con.execute("DELETE FROM questionnaire_response WHERE id = (SELECT max(id) FROM questionnaire_response)")
    con.commit()
    con.close()
    code, out, _ = _cli(capsys, "status", *w)
    assert code == 0
    assert (f"data: 2 trials checked: {clean['samples_stored']} of {clean['ticks'] + 37} loop samples stored "
            "(37 dropped); missing: 2 trials, 1 questionnaire answers") in out
    assert f"PTY-AAAAA trial {trial_id}" in out and "37 samples dropped" in out
    assert "PTY-BBBBB no session" in out and "(withdrew)" in out
    assert not [line for line in out.splitlines() if "PTY-CCCCC" in line and "missing" in line]  # not started yet
    assert out.index("data: 2 trials checked") < out.index("progress (done/planned")  # the totals near the top
    code, out, _ = _cli(capsys, "status", "--json", *w)
    data = json.loads(out)["data"]
    assert data["totals"]["dropped_samples"] == 37 and data["totals"]["answers_missing"] == 1
    assert {g["kind"] for g in data["gaps"]} == {"dropped_samples", "trial_missing", "answers_missing"}
