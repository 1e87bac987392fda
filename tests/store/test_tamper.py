"""Tampering outside studyctl is detected and named (issue 19), on SQLite and PostgreSQL.

One scripted person session (trials with outcomes and location reports, events, Likert answers, sample
chunks) is recorded once per backend; every test works on its own copy (SQLite: the file and its head
file; PostgreSQL: ``CREATE DATABASE … TEMPLATE`` plus the head file), drops the append-only triggers as an
attacker with database access would, changes one thing, and expects ``studyctl audit verify`` to exit
non-zero naming that record (and ``db check`` for the sample chunks).
"""

from __future__ import annotations

import itertools
import json
import os
import shutil
from pathlib import Path

import pytest
import yaml
from sqlalchemy import create_engine, delete, func, insert, select, text, update

from studyctl.cli.app import main
from studyctl.engine.api import run_session
from studyctl.store.anchor import anchor_path
from studyctl.store.audit import row_hash
from studyctl.store.db import parse_url
from studyctl.store.enrollment import enroll
from studyctl.store.models import (
    AuditHead,
    AuditLog,
    Event,
    LocationReport,
    QuestionnaireResponse,
    SampleChunk,
    Trial,
)
from studyctl.store.workspace import init_workspace, open_study

PROTOCOL = Path(__file__).parents[1] / "engine" / "data" / "pty_protocol.yaml"
SCRIPT = {
    "likert": {"easy": [4, 5, 2], "prefer_feedback": [4]},
    "trials": {
        1: [{"t": 1.0, "request": "report", "answer": "8 1"}, {"t": 2.0, "request": "report", "answer": "3 4"},
            {"t": 5.0, "request": "finish"}],
        2: [{"t": 2.5, "request": "finish"}],
    },
}
_copies = itertools.count()


def _record(ws: Path, db: str | None) -> str:
    init_workspace(ws, protocol=str(PROTOCOL), db=db)
    answers = ws / "answers.yaml"
    answers.write_text(yaml.safe_dump(SCRIPT))
    with open_study(workspace=ws) as o:
        enroll(o.store, code="TMP-AAAAA")
        result = run_session(o.store, "TMP-AAAAA", virtual=False, script=answers)
        assert result.status == "completed"
        return o.store.db.url.render_as_string(hide_password=False)


@pytest.fixture(scope="module")
def recorded(request, tmp_path_factory):
    """backend → URL of the recorded study (and, for PostgreSQL, its head file)."""
    out = {}
    out["sqlite"] = _record(tmp_path_factory.mktemp("tamper-sqlite") / "ws", None)
    pg = request.getfixturevalue("pg_server")
    heads = tmp_path_factory.mktemp("tamper-heads")
    old = os.environ.get("STUDYCTL_AUDIT_HEAD_DIR")
    os.environ["STUDYCTL_AUDIT_HEAD_DIR"] = str(heads)
    try:
        out["postgresql"] = _record(tmp_path_factory.mktemp("tamper-pg") / "ws", pg.create_database("tamper_src"))
        out["postgresql_head"] = anchor_path(parse_url(out["postgresql"]))
    finally:
        if old is None:
            os.environ.pop("STUDYCTL_AUDIT_HEAD_DIR")
        else:
            os.environ["STUDYCTL_AUDIT_HEAD_DIR"] = old
    return out


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def copy_url(request, recorded, tmp_path):
    """A fresh copy of the recorded study (with its head file) to tamper with."""
    if request.param == "sqlite":
        src = Path(parse_url(recorded["sqlite"]).database)
        dst = tmp_path / "study.db"
        shutil.copyfile(src, dst)
        shutil.copyfile(f"{src}.head", f"{dst}.head")
        return f"sqlite:///{dst}"
    pg = request.getfixturevalue("pg_server")
    url = pg.create_database(f"tamper_{next(_copies)}", template="tamper_src")
    head = anchor_path(parse_url(url))
    head.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(recorded["postgresql_head"], head)
    return url


def _tamper(url: str, *statements) -> None:
    """Run statements as an attacker: the append-only triggers dropped, no studyctl code involved."""
    engine = create_engine(parse_url(url))
    try:
        with engine.begin() as conn:
            for table in ("event", "audit_log"):
                if engine.dialect.name == "sqlite":
                    for what in ("update", "delete"):
                        conn.execute(text(f"DROP TRIGGER IF EXISTS {table}_no_{what}"))
                else:
                    conn.execute(text(f"ALTER TABLE {table} DISABLE TRIGGER USER"))
            for stmt in statements:
                stmt(conn) if callable(stmt) else conn.execute(stmt)
    finally:
        engine.dispose()


def _verify(url: str, capsys) -> tuple[int, str]:
    code = main(["audit", "verify", "--db", url])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def _one(conn, stmt):
    return conn.execute(stmt).first()


@pytest.mark.slow
def test_untouched_study_verifies(copy_url, capsys):
    code, out = _verify(copy_url, capsys)
    assert code == 0, out
    assert "Audit log intact" in out and "records sealed and unchanged" in out
    assert main(["db", "check", "--db", copy_url]) == 0, capsys.readouterr()


# ----------------------------------------------------------------------------------- the tampering

def _last_trial(conn):
    return conn.execute(select(Trial.id, Trial.outcome).where(Trial.status == "completed")
                        .order_by(Trial.id.desc())).first()


def _delete_last(conn, model, label):
    rid = conn.execute(select(func.max(model.id))).scalar()
    conn.execute(delete(model).where(model.id == rid))
    return rf"{label} {rid} deleted"


def _insert_copy(conn, model, label, *, newest=True, bump=None):
    """A copy of the newest (or the oldest) row under a new id; ``bump``: a column advanced so the copy is unique."""
    row = conn.execute(select(model).order_by(model.id.desc() if newest else model.id)).mappings().first()
    values = {k: v for k, v in row.items() if k != "id"}
    if bump:
        values[bump] += 1
    new = conn.execute(insert(model).values(**values).returning(model.id)).scalar()
    return rf"{label} {new} inserted"


def edit_audit(conn):
    conn.execute(update(AuditLog).where(AuditLog.id == 3).values(actor="mallory"))
    return r"audit row 3 \(.*\) was edited"


def delete_audit(conn):
    conn.execute(delete(AuditLog).where(AuditLog.id == 4))
    return r"audit row\(s\) 4 deleted"


def insert_audit(conn):
    """A well-formed, correctly chained row appended at the end with the head row advanced to match."""
    count, prev = conn.execute(select(AuditHead.count, AuditHead.hash)).one()
    row = {"id": count + 1, "at": "2026-01-01T00:00:00+00:00", "actor": "mallory", "action": "trial.status",
           "entity": "trial", "entity_id": "1", "details": "{}"}
    digest = row_hash(prev, row)
    conn.execute(insert(AuditLog).values(**row, prev_hash=prev, hash=digest))
    conn.execute(update(AuditHead).values(count=count + 1, hash=digest))
    return rf"audit row\(s\) {count + 1} are not in the head file"


def truncate_tail(conn):
    """The last two audit rows deleted and audit_head rewritten to the new end: consistent inside the database."""
    count = conn.execute(select(AuditHead.count)).scalar()
    conn.execute(delete(AuditLog).where(AuditLog.id > count - 2))
    prev = conn.execute(select(AuditLog.hash).where(AuditLog.id == count - 2)).scalar()
    conn.execute(update(AuditHead).values(count=count - 2, hash=prev))
    return rf"tail truncated: the head file .* records {count} audit rows"


def edit_trial(conn):
    tid, _ = _last_trial(conn)
    conn.execute(update(Trial).where(Trial.id == tid).values(condition="linear_x"))
    return rf"trial {tid} edited: .* its fields changed"


def delete_trial(conn):
    """The trial with everything hanging off it (a whole trial removed, as in the issue)."""
    tid, _ = _last_trial(conn)
    for model in (Event, SampleChunk, LocationReport, QuestionnaireResponse):
        conn.execute(delete(model).where(model.trial_id == tid))
    conn.execute(update(Trial).where(Trial.replaces_trial_id == tid).values(replaces_trial_id=None))
    conn.execute(delete(Trial).where(Trial.id == tid))
    return rf"trial {tid} deleted"


def insert_trial(conn):
    return _insert_copy(conn, Trial, "trial")


def edit_outcome(conn):
    tid, outcome = _last_trial(conn)
    outcome = dict(outcome)
    outcome["duration_s"] = 1.0
    conn.execute(update(Trial).where(Trial.id == tid).values(outcome=outcome))
    return rf"trial {tid} edited: .* its outcome changed"


def edit_event(conn):
    eid, payload = _one(conn, select(Event.id, Event.payload).where(Event.kind == "trial_end"))
    conn.execute(update(Event).where(Event.id == eid).values(payload={**payload, "status": "aborted"}))
    return rf"event {eid} edited"


def delete_event(conn):
    return _delete_last(conn, Event, "event")


def insert_event(conn):
    return _insert_copy(conn, Event, "event", bump="seq")


def edit_answer(conn):
    aid, code = _one(conn, select(QuestionnaireResponse.id, QuestionnaireResponse.code)
                     .order_by(QuestionnaireResponse.id))
    conn.execute(update(QuestionnaireResponse).where(QuestionnaireResponse.id == aid)
                 .values(code=1 if code != 1 else 5))
    return rf"answer {aid} edited"


def delete_answer(conn):
    return _delete_last(conn, QuestionnaireResponse, "answer")


def insert_answer(conn):
    return _insert_copy(conn, QuestionnaireResponse, "answer", newest=False)


def edit_report(conn):
    rid, payload = _one(conn, select(LocationReport.id, LocationReport.payload))
    conn.execute(update(LocationReport).where(LocationReport.id == rid).values(payload={**payload, "cell": [1, 1]}))
    return rf"location report {rid} edited"


def zero_chunk(conn):
    cid, data = _one(conn, select(SampleChunk.id, SampleChunk.data).order_by(SampleChunk.id))
    conn.execute(update(SampleChunk).where(SampleChunk.id == cid).values(data=bytes(len(data))))
    return rf"sample chunk {cid} edited: .* no longer match its digest"


def rehash_chunk(conn):
    """Samples changed and the chunk's own digest recomputed: the sealed digest still tells."""
    from studyctl.store.records import chunk_digest

    row = conn.execute(select(SampleChunk).order_by(SampleChunk.id)).mappings().first()
    data = bytes(len(row["data"]))
    conn.execute(update(SampleChunk).where(SampleChunk.id == row["id"])
                 .values(data=data, digest=chunk_digest(dict(row), row["t"], data)))
    return rf"sample chunk {row['id']} edited: .* changed since sealed"


def delete_chunk(conn):
    return _delete_last(conn, SampleChunk, "sample chunk")


def insert_chunk(conn):
    return _insert_copy(conn, SampleChunk, "sample chunk", bump="chunk_index")


CASES = [edit_audit, delete_audit, insert_audit, truncate_tail, edit_trial, delete_trial, insert_trial, edit_outcome,
         edit_event, delete_event, insert_event, edit_answer, delete_answer, insert_answer, edit_report, zero_chunk,
         rehash_chunk, delete_chunk, insert_chunk]


@pytest.mark.parametrize("case", CASES, ids=[c.__name__ for c in CASES])
@pytest.mark.slow
def test_tampering_is_detected_and_named(copy_url, case, capsys):
    import re

    expected: list[str] = []
    _tamper(copy_url, lambda conn: expected.append(case(conn)))
    code, out = _verify(copy_url, capsys)
    if case is insert_audit and copy_url.startswith("postgresql"):
        # Other sites write a shared PostgreSQL database, so rows after this machine's head file are only a note
        # there; a correctly chained forged row needs the head noted in the lab notebook (--head) to be caught.
        assert "note: audit row(s)" in out and "are not in the head file" in out
        # with one machine's head file standing for every writer (--single-site) the same forgery is an error
        assert main(["audit", "verify", "--db", copy_url, "--single-site"]) == 1
        captured = capsys.readouterr()
        assert re.search(expected[0], captured.out + captured.err), captured
        return
    assert code == 1, out
    assert re.search(expected[0], out), f"{expected[0]!r} not in:\n{out}"
    assert out.strip().splitlines()[-1].startswith("Error: the study database fails verification")
    if "chunk" in case.__name__:
        assert main(["db", "check", "--db", copy_url]) != 0
        assert "FAIL sample digests" in capsys.readouterr().out


def test_event_list_in_seals_is_json(copy_url):
    """Seals are ordinary audit rows whose details list digests per record kind (readable with audit show)."""
    engine = create_engine(parse_url(copy_url))
    try:
        with engine.connect() as conn:
            details = [json.loads(d) for d in conn.execute(select(AuditLog.details)
                                                           .where(AuditLog.action == "records.seal")).scalars()]
    finally:
        engine.dispose()
    kinds = set().union(*details)
    assert {"trial", "event", "answer", "report", "chunk"} <= kinds


def test_audit_show_hides_seals_unless_asked(copy_url, capsys):
    assert main(["audit", "show", "--db", copy_url, "--last", "500"]) == 0
    plain = capsys.readouterr().out
    assert "session.update" in plain and "records.seal" not in plain
    assert main(["audit", "show", "--db", copy_url, "--last", "500", "--seals"]) == 0
    assert "records.seal" in capsys.readouterr().out
