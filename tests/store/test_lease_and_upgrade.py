"""Session leases in the store (stale owners on other hosts, a lease lost to a take-over) and an existing
database upgraded to sealed records, on SQLite and PostgreSQL."""

from __future__ import annotations

from datetime import timedelta

import pytest
from alembic import command
from sqlalchemy import text

from studyctl.errors import SessionError
from studyctl.store import StudyStore
from studyctl.store.db import Database, alembic_config
from studyctl.store.integrity import verify_integrity
from studyctl.store.lease import STALE_S, take_lease
from studyctl.store.models import SessionLease, utcnow


def _session(store: StudyStore) -> int:
    study = store.create_study("s")
    p = store.add_participant(study.id, "P-1")
    return store.start_session(p.id).id


def _foreign_lease(store: StudyStore, sid: int, *, age_s: float) -> None:
    with store.in_transaction() as tx:
        then = utcnow() - timedelta(seconds=age_s)
        tx.add(SessionLease(session_id=sid, token="f" * 32, pid=4242, host="other-host.example", acquired_at=then,
                            heartbeat_at=then))


def test_lease_of_another_host_needs_take_over_once_stale(store):
    sid = _session(store)
    _foreign_lease(store, sid, age_s=STALE_S + 60)
    if store.db.dialect == "postgresql":
        # PostgreSQL knows: nobody holds the session's advisory lock, so the owner is gone, whatever its host
        with store.in_transaction() as tx:
            handle = take_lease(store.db, tx, sid)
        handle.release()
        assert "session.take_over" in list(store.audit_frame()["action"])
        return
    with pytest.raises(SessionError, match=r"session \d+ is being run by pid 4242 on other-host.example since .* "
                                           r"\(no heartbeat for \d+ s\); if that process is gone, studyctl resume "
                                           r"\d+ --take-over"):
        with store.in_transaction() as tx:
            take_lease(store.db, tx, sid)
    with store.in_transaction() as tx:
        handle = take_lease(store.db, tx, sid, take_over=True)
    handle.release()
    row = store.audit_frame().iloc[-1]
    assert row.action == "session.take_over" and "other-host.example" in row.details and "--take-over" in row.details


def test_fresh_lease_of_another_host_is_never_taken(sqlite_store):
    sid = _session(sqlite_store)
    _foreign_lease(sqlite_store, sid, age_s=1)
    for take_over in (False, True):
        with pytest.raises(SessionError, match="being run by pid 4242 on other-host.example"):
            with sqlite_store.in_transaction() as tx:
                take_lease(sqlite_store.db, tx, sid, take_over=take_over)


def test_a_lease_taken_over_stops_the_old_writer(store):
    sid = _session(store)
    with store.in_transaction() as tx:
        handle = take_lease(store.db, tx, sid)
    try:
        with store.in_transaction() as tx:
            handle.verify(tx)  # still ours
        with store.db.engine.begin() as conn:  # what a take-over elsewhere leaves behind
            conn.execute(text("UPDATE session_lease SET token = :t"), {"t": "0" * 32})
        with pytest.raises(SessionError, match="was taken over by another process"):
            with store.in_transaction() as tx:
                handle.verify(tx)
    finally:
        handle.release()
    with store.reading() as s:
        assert s.get(SessionLease, sid) is not None  # release leaves the new owner's lease alone


def test_existing_database_upgrades_and_its_old_records_are_noted_not_flagged(empty_db_url):
    if empty_db_url.startswith("sqlite"):
        import sqlite3

        sqlite3.connect(empty_db_url.removeprefix("sqlite:///")).close()
    with Database.open(empty_db_url, check_schema=False) as db:
        with db.engine.begin() as conn:
            command.upgrade(alembic_config(connection=conn), "0001")
        with db.engine.begin() as conn:  # data written by a studyctl before sealed records
            conn.execute(text("INSERT INTO study (id, name, seed, studyctl_version, created_at) "
                              "VALUES (1, 's', 1, '0.0', CURRENT_TIMESTAMP)"))
            conn.execute(text("INSERT INTO participant (id, study_id, code, status, enrolled_at) "
                              "VALUES (1, 1, 'P-1', 'active', CURRENT_TIMESTAMP)"))
            conn.execute(text("INSERT INTO session (id, participant_id, status, started_at, resume_count) "
                              "VALUES (1, 1, 'completed', CURRENT_TIMESTAMP, 0)"))
            conn.execute(text("INSERT INTO event (id, session_id, seq, t_mono, t_wall, kind) "
                              "VALUES (1, 1, 1, 0.0, CURRENT_TIMESTAMP, 'old')"))
        db.upgrade()
        report = verify_integrity(db)
        assert report.ok, report.problems
        assert any("written before this database was upgraded" in n for n in report.notes)
        with db.engine.begin() as conn:  # a record slipped in after the upgrade is flagged
            conn.execute(text("INSERT INTO event (id, session_id, seq, t_mono, t_wall, kind) "
                              "VALUES (2, 1, 2, 0.0, CURRENT_TIMESTAMP, 'new')"))
        report = verify_integrity(db)
        assert [p.line().split(":")[0] for p in report.records.problems] == ["event 2 inserted"]
