"""The hash-chained audit log detects every edited, deleted or re-hashed row, and says which."""

from __future__ import annotations

import hashlib

import pytest
from sqlalchemy import text

from studyctl.cli.app import main
from studyctl.store.audit import GENESIS_HASH, canonical_json, row_hash

# Tampering drops (SQLite) or disables (PostgreSQL) the append-only triggers; SQLite databases are
# per-test copies and the shared PostgreSQL test database re-enables them before each test.


def _populate(store, n: int = 6) -> None:
    study = store.create_study("s")
    for i in range(n - 1):
        store.add_participant(study.id, f"P{i}")


def _tamper(store, *sql: str, **params) -> None:
    """Run SQL as an attacker with direct database access would: bypass the append-only triggers."""
    with store.db.engine.begin() as conn:
        if store.db.dialect == "sqlite":
            conn.execute(text("DROP TRIGGER audit_log_no_update"))
            conn.execute(text("DROP TRIGGER audit_log_no_delete"))
        else:
            conn.execute(text("ALTER TABLE audit_log DISABLE TRIGGER audit_log_append_only"))
        for statement in sql:
            conn.execute(text(statement), params)


def test_intact_chain_verifies(store):
    _populate(store)
    report = store.verify_audit()
    assert report.ok and report.rows == 6
    frame = store.audit_frame()
    prev = GENESIS_HASH
    for row in frame.itertuples(index=False):
        body = canonical_json({"id": row.id, "at": row.at, "actor": row.actor, "action": row.action,
                               "entity": row.entity, "entity_id": row.entity_id, "details": row.details})
        assert row.hash == hashlib.sha256((prev + body).encode()).hexdigest()
        prev = row.hash
    assert report.head_hash == prev
    assert report.to_frame().empty


def test_edited_row_is_named(store):
    _populate(store)
    _tamper(store, "UPDATE audit_log SET details = replace(details, 'P2', 'P9') WHERE id = 4")
    report = store.verify_audit()
    assert not report.ok
    assert report.bad_ids == (4,)
    assert "audit row 4 (participant.enroll) was edited" in report.problems[0]


def test_rehashed_row_breaks_the_next_link(store):
    _populate(store)
    frame = store.audit_frame()
    row = frame[frame.id == 3].iloc[0]
    fields = {k: row[k] for k in ("id", "at", "actor", "action", "entity", "entity_id")}
    fields["details"] = row["details"].replace("P1", "PX")
    forged = row_hash(frame[frame.id == 2].iloc[0]["hash"], fields)
    _tamper(store, "UPDATE audit_log SET details = :d, hash = :h WHERE id = 3", d=fields["details"], h=forged)
    report = store.verify_audit()
    assert report.bad_ids == (4,)
    assert "audit row 4" in report.problems[0] and "prev_hash" in report.problems[0]


def test_deleted_middle_row_is_named(store):
    _populate(store)
    _tamper(store, "DELETE FROM audit_log WHERE id = 3")
    report = store.verify_audit()
    assert not report.ok
    assert any("audit row(s) 3 deleted" in p for p in report.problems)


def test_deleted_tail_is_detected(store):
    _populate(store)
    _tamper(store, "DELETE FROM audit_log WHERE id = 6")
    report = store.verify_audit()
    assert report.problems == (
        "the audit log ends at row 5 but its head records 6 rows: audit row(s) 6 at the end were deleted (or the "
        "head was edited)",)


def test_cli_verify_exit_codes(store, capsys):
    _populate(store)
    url = str(store.db.url.render_as_string(hide_password=False))
    assert main(["audit", "verify", "--db", url]) == 0
    assert "Audit log intact: 6 rows" in capsys.readouterr().out
    _tamper(store, "UPDATE audit_log SET actor = 'mallory' WHERE id = 2")
    assert main(["audit", "verify", "--db", url]) == 1
    err = capsys.readouterr().err
    assert "audit row 2 (participant.enroll) was edited" in err
    assert err.strip().splitlines()[-1].startswith("Error: the study database fails verification")


def test_audit_details_must_be_json(store):
    from studyctl.errors import UsageError

    with pytest.raises(UsageError, match="finite"):
        store.audit("note", details={"x": float("nan")})
    with pytest.raises(TypeError, match="JSON values"):
        store.audit("note", details={"x": object()})
