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
        # PostgreSQL knows: nobody holds the session's advisory lock, so the owner is gone, whatever its host;
        # still taken over only when asked to
        with pytest.raises(SessionError, match=r"which is gone \(its PostgreSQL connection is closed\).*--take-over"):
            with store.in_transaction() as tx:
                take_lease(store.db, tx, sid)
        with store.in_transaction() as tx:
            handle = take_lease(store.db, tx, sid, take_over=True)
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


def test_a_writer_that_lost_its_lease_flushes_no_samples(store):
    """Sample flushes check the lease in their own transaction: after a take-over elsewhere the old writer's
    buffered samples are refused (SessionError), and nothing of them is stored."""
    sid = _session(store)
    trial = store.add_trial(sid, plan_position=1, condition="a", status="running")
    with store.in_transaction() as tx:
        handle = take_lease(store.db, tx, sid)
    try:
        writer = store.sample_writer(trial.id, ["f"], flush_interval_s=1e9, guard=handle.verify)
        writer.append(0.0, [1.0])
        assert writer.flush() == 1  # ours: stored
        writer.append(0.1, [2.0])
        with store.db.engine.begin() as conn:  # what a take-over elsewhere leaves behind
            conn.execute(text("UPDATE session_lease SET token = :t"), {"t": "0" * 32})
        with pytest.raises(SessionError, match="was taken over by another process"):
            writer.flush()
    finally:
        handle.release()
    assert list(store.read_samples(trial.id)["f"]) == [1.0]  # the refused flush left nothing behind


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


def test_records_written_through_the_library_are_sealed_and_raw_inserts_are_named(store):
    """A study written with the store API directly (no session engine) is studyctl's own writing: every record is
    sealed in the transaction that writes it, so `audit verify` passes. A row added behind studyctl's back with SQL
    is still named as inserted."""
    sid = _session(store)
    trial = store.add_trial(sid, plan_position=1, condition="a", status="running")
    store.update_trial(trial.id, status="completed", outcome={"duration_s": 3.0})
    store.append_event(sid, "note", {"x": 1}, t_mono=0.5, trial_id=trial.id)
    pid = store.get_session(sid).participant_id
    store.record_response(pid, instrument="i", instrument_version="1", item="q", code=3, session_id=sid)
    store.record_location_report(trial.id, t=1.0, payload={"cell": "A1"})
    with store.sample_writer(trial.id, ["f"]) as writer:
        writer.append(0.0, [1.0])
    store.update_session(sid, status="completed")
    report = verify_integrity(store.db)
    assert report.ok, report.problems
    assert report.records.checked == {"trial": 1, "event": 1, "answer": 1, "report": 1, "chunk": 1}
    with store.db.engine.begin() as conn:
        conn.execute(text("INSERT INTO event (session_id, seq, t_mono, t_wall, kind) "
                          "VALUES (:s, 99, 0.0, CURRENT_TIMESTAMP, 'forged')"), {"s": sid})
    report = verify_integrity(store.db)
    assert [p.line().split(":")[0] for p in report.records.problems] == ["event 2 inserted"]


@pytest.mark.slow
def test_withdrawing_seals_the_records_of_the_session_it_closes(tmp_path):
    """A session cut short by a crash holds records written after its last seal (pending while it could be
    resumed). Withdrawing the participant closes it: those records are kept as they stand and sealed, not
    reported as inserted."""
    from studyctl.store.coordination import withdraw  # noqa: PLC0415
    from studyctl.store.enrollment import enroll  # noqa: PLC0415
    from studyctl.store.workspace import init_workspace, open_study  # noqa: PLC0415

    init_workspace(tmp_path / "ws", protocol="bio_inspired_palpation")
    with open_study(workspace=tmp_path / "ws") as o:
        code = enroll(o.store, "novice", study=o.study.name).code
        p = o.store.get_participant(o.study.id, code)
        sid = o.store.start_session(p.id).id
        o.store.update_session(sid, status="running")
        tid = o.store.add_trial(sid, plan_position=1, condition="linear", status="running").id
        with o.store.db.engine.begin() as conn:  # what the engine had not sealed yet when it was killed
            conn.execute(text("INSERT INTO event (session_id, trial_id, seq, t_mono, t_wall, kind) "
                              "VALUES (:s, :t, 50, 0.1, CURRENT_TIMESTAMP, 'trial_loop_start')"),
                         {"s": sid, "t": tid})
        report = verify_integrity(o.store.db)
        assert report.ok and any("pending" in n for n in report.notes), (report.problems, report.notes)
        withdraw(o.store, code, reason="left", study=o.study.name)
        report = verify_integrity(o.store.db)
        assert report.ok, report.problems
