"""withdraw --delete-data: the participant's records erased through the audited erase permit (migration 0004),
the chain still verifies and reports the erasure, on SQLite and PostgreSQL; misuse is one Error line and
writes nothing; an erasure never half-happens."""

from __future__ import annotations

import itertools
import json
import os
import socket
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd
import pytest
import yaml
from sqlalchemy import func, insert, select, text

from studyctl.cli.app import main
from studyctl.engine.api import run_session
from studyctl.store.enrollment import enroll
from studyctl.store.models import (
    AuditLog,
    ErasePermit,
    Event,
    Participant,
    QuestionnaireResponse,
    SampleChunk,
    Session,
    SessionLease,
    Trial,
)
from studyctl.store.workspace import init_workspace, open_study

PROTOCOL = Path(__file__).parents[1] / "engine" / "data" / "pty_protocol.yaml"
SCRIPT = {"likert": {"easy": [4, 5], "prefer_feedback": [4]},
          "trials": {1: [{"t": 1.0, "request": "report", "answer": "8 1"}, {"t": 2.0, "request": "finish"}],
                     2: [{"t": 2.5, "request": "finish"}]}}
CODES = ("PTY-AAAAA", "PTY-BBBBB")
_dbs = itertools.count()


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def backend_db(request) -> str | None:
    """None: the workspace's own SQLite file; else a new, empty PostgreSQL database that init migrates."""
    if request.param == "sqlite":
        return None
    return request.getfixturevalue("pg_server").create_database(f"erasure_{os.getpid()}_{next(_dbs)}")


def _study(tmp_path: Path, db: str | None) -> Path:
    ws = tmp_path / "ws"
    init_workspace(ws, protocol=str(PROTOCOL), db=db)
    answers = tmp_path / "answers.yaml"
    answers.write_text(yaml.safe_dump(SCRIPT))
    with open_study(workspace=ws) as o:
        for code in CODES:
            enroll(o.store, code=code)
            assert run_session(o.store, code, virtual=False, script=answers).status == "completed"
    return ws


def _cli(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def _counts(ws: Path, code: str) -> dict[str, int]:
    with open_study(workspace=ws) as o, o.store.reading() as tx:
        pid = tx.scalar(select(Participant.id).where(Participant.code == code))
        sessions = select(Session.id).where(Session.participant_id == pid).scalar_subquery()
        trials = select(Trial.id).where(Trial.participant_id == pid).scalar_subquery()
        n = lambda q: int(tx.scalar(select(func.count()).select_from(q.subquery())))  # noqa: E731
        return {"session": n(select(Session.id).where(Session.participant_id == pid)),
                "trial": n(select(Trial.id).where(Trial.participant_id == pid)),
                "event": n(select(Event.id).where(Event.session_id.in_(sessions))),
                "answer": n(select(QuestionnaireResponse.id).where(QuestionnaireResponse.participant_id == pid)),
                "chunk": n(select(SampleChunk.id).where(SampleChunk.trial_id.in_(trials))),
                "audit": int(tx.scalar(select(func.count()).select_from(AuditLog)))}


@pytest.mark.slow
def test_delete_data_erases_one_participant_and_the_chain_still_verifies(backend_db, tmp_path, capsys):
    ws = _study(tmp_path, backend_db)
    w = ("-w", str(ws))
    gone, kept = CODES[1], CODES[0]  # the newest records go: SQLite hands their ids out again
    before_gone, before_kept = _counts(ws, gone), _counts(ws, kept)
    assert min(before_gone[k] for k in ("session", "trial", "event", "answer", "chunk")) > 0
    assert _cli(capsys, "note", "B sneezed", "--session", "2", *w)[0] == 0

    code, out, err = _cli(capsys, "withdraw", gone, "--reason", "asked for erasure", "--delete-data", "--json", *w)
    assert code == 0, err
    result = json.loads(out)
    assert result["keep_data"] is False and result["erased"]["trial"] == before_gone["trial"]
    assert result["erased"]["event"] == before_gone["event"] and result["erased"]["session"] == 1

    after_gone, after_kept = _counts(ws, gone), _counts(ws, kept)
    assert {k: v for k, v in after_gone.items() if k != "audit"} == dict.fromkeys(after_gone.keys() - {"audit"}, 0)
    assert {k: v for k, v in after_kept.items() if k != "audit"} == \
        {k: v for k, v in before_kept.items() if k != "audit"}
    with open_study(workspace=ws) as o, o.store.reading() as tx:
        assert tx.scalar(select(func.count()).select_from(ErasePermit)) == 0  # no permit outlives its transaction
        b = tx.scalar(select(Participant).where(Participant.code == gone))
        assert b.status == "withdrawn" and b.sequence_slot is not None  # the allocation is kept
        erase = tx.scalar(select(AuditLog).where(AuditLog.action == "participant.erase"))
        assert erase is not None and json.loads(erase.details)["code"] == gone
        erase_id = erase.id

    code, out, err = _cli(capsys, "audit", "verify", "--json", *w)
    assert code == 0, err
    report = json.loads(out)
    assert report["erased"]["event"] == before_gone["event"] and report["erased"]["chunk"] == before_gone["chunk"]
    assert "erased at participants' request" in err and "each matches its seal" in err
    code, out, _ = _cli(capsys, "audit", "verify", *w)
    assert code == 0 and "erased as audited:" in out

    # a new participant's session after the erasure (on SQLite it reuses the erased ids): still verifies, and the
    # note on the erased session is not taken for a note on the new one
    answers = tmp_path / "answers.yaml"
    with open_study(workspace=ws) as o:
        enroll(o.store, code="PTY-CCCCC")
        new = run_session(o.store, "PTY-CCCCC", virtual=False, script=answers)
    if backend_db is None:
        assert new.session_id == 2  # SQLite: the erased session's id again (PostgreSQL's sequences never reuse)
    code, out, err = _cli(capsys, "audit", "verify", *w)
    assert code == 0, err
    out_dir = tmp_path / "export"
    assert main(["export", str(out_dir), "-w", str(ws), "--no-samples"]) == 0
    records = pd.read_csv(out_dir / "records.csv")
    assert records.record.tolist() == ["withdrawal", "erasure"], new.session_id  # the note left with B's session
    trials = pd.read_csv(out_dir / "trials.csv")
    assert set(trials.participant) == {kept, "PTY-CCCCC"}

    # the permit opens only what an erasure lists: events of A deleted under B's erasure read as deleted
    with open_study(workspace=ws) as o:
        with pytest.raises(Exception, match="append-only"), o.store.db.engine.begin() as conn:
            conn.execute(text("DELETE FROM event WHERE session_id = 1"))
        with o.store.db.engine.begin() as conn:
            conn.execute(insert(ErasePermit).values(session_id=1, audit_id=erase_id))
            conn.execute(text("DELETE FROM event WHERE id = (SELECT MAX(id) FROM event WHERE session_id = 1)"))
            conn.execute(text("DELETE FROM erase_permit"))
    code, _, err = _cli(capsys, "audit", "verify", *w)
    assert code != 0 and "deleted: sealed in audit row" in err


@pytest.mark.slow
def test_erasure_later_misuse_and_nothing_half_written(tmp_path, capsys):
    ws = _study(tmp_path, None)
    w = ("-w", str(ws))
    assert _cli(capsys, "withdraw", CODES[0], "--reason", "moved away", *w)[0] == 0  # data kept
    kept = _counts(ws, CODES[0])
    assert kept["trial"] > 0

    def refused(args: tuple[str, ...], message: str) -> None:
        before = _counts(ws, CODES[0]), _counts(ws, CODES[1])
        code, _, err = _cli(capsys, *args, *w)
        lines = [x for x in err.splitlines() if x.strip()]
        assert code != 0 and len(lines) == 1 and lines[0].startswith("Error:") and message in lines[0], (args, err)
        assert (_counts(ws, CODES[0]), _counts(ws, CODES[1])) == before, args

    refused(("withdraw", CODES[0], "--reason", "again"), "add --delete-data to erase")
    refused(("withdraw", "PTY-AAAAX", "--reason", "x", "--delete-data"), "did you mean")
    refused(("withdraw", CODES[0], "--reason", " ", "--delete-data"), "reason is empty")

    # a session still being run (this process holds its lease) is not erased
    with open_study(workspace=ws) as o, o.store.in_transaction() as tx:
        now = datetime.now(UTC)
        tx.add(SessionLease(session_id=1, token="t" * 32, pid=os.getpid(), host=socket.gethostname(),
                            acquired_at=now, heartbeat_at=now))
    refused(("withdraw", CODES[0], "--reason", "erase please", "--delete-data"), "stop that session")
    with open_study(workspace=ws) as o, o.store.in_transaction() as tx:
        tx.query(SessionLease).delete()

    # a table added later that still points at a trial: the erasure fails whole (rolled back)
    with open_study(workspace=ws) as o, o.store.db.engine.begin() as conn:
        conn.execute(text("CREATE TABLE later (id INTEGER PRIMARY KEY, trial_id INTEGER REFERENCES trial(id))"))
        conn.execute(text("INSERT INTO later (trial_id) SELECT MIN(id) FROM trial WHERE participant_id = 1"))
    refused(("withdraw", CODES[0], "--reason", "erase please", "--delete-data"), "nothing was erased")
    with open_study(workspace=ws) as o, o.store.db.engine.begin() as conn:
        conn.execute(text("DROP TABLE later"))

    # the erasure asked for after a withdrawal with data kept
    code, out, err = _cli(capsys, "withdraw", CODES[0], "--reason", "erase please", "--delete-data", *w)
    assert code == 0, err
    assert f"Erased the recorded data of {CODES[0]}: 1 session, {kept['trial']} trials" in out
    assert _counts(ws, CODES[0])["trial"] == 0
    refused(("withdraw", CODES[0], "--reason", "again", "--delete-data"), "nothing recorded of them is left")
    assert _cli(capsys, "audit", "verify", *w)[0] == 0
