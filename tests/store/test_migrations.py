"""Schema migrations: empty → head on both backends, models match the migrated schema, version errors."""

from __future__ import annotations

import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import text

from studyctl.errors import SchemaVersionError, StoreError
from studyctl.store.db import Database, alembic_config, head_revision
from studyctl.store.models import Base


def test_upgrade_from_empty_matches_models(empty_db_url):
    if empty_db_url.startswith("sqlite"):
        db = Database.create(empty_db_url)
    else:
        db = Database.open(empty_db_url, check_schema=False)
        assert db.schema_state().current is None
        db.upgrade()
    with db:
        assert db.schema_state().current == head_revision()
        with db.engine.connect() as conn:
            diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
        assert diff == [], f"models and migrations disagree; add a revision: {diff}"


def test_downgrade_to_base_and_back(isolated_db_url):
    db_url = isolated_db_url
    with Database.open(db_url) as db:
        with db.engine.begin() as conn:
            command.downgrade(alembic_config(connection=conn), "base")
        state = db.schema_state()
        assert state.current is None
        db.upgrade()
        assert db.schema_state().up_to_date


def _stamp(db_url: str, revision: str) -> None:
    with Database.open(db_url) as db, db.engine.begin() as conn:
        conn.execute(text("UPDATE alembic_version SET version_num = :v"), {"v": revision})


def test_newer_revision_is_refused_with_what_to_do(isolated_db_url):
    db_url = isolated_db_url
    _stamp(db_url, "9999_from_the_future")
    with pytest.raises(SchemaVersionError) as err:
        Database.open(db_url)
    msg = str(err.value)
    assert "9999_from_the_future" in msg and "newer studyctl" in msg and "pip install -U studyctl" in msg
    # Upgrading cannot help either: it refuses instead of guessing.
    with Database.open(db_url, check_schema=False) as db, pytest.raises(SchemaVersionError):
        db.upgrade()


def test_older_schema_asks_for_db_upgrade(isolated_db_url):
    db_url = isolated_db_url
    with Database.open(db_url) as db, db.engine.begin() as conn:
        command.downgrade(alembic_config(connection=conn), "base")
    with pytest.raises(SchemaVersionError, match="studyctl db upgrade"):
        Database.open(db_url)


def test_foreign_database_is_not_mistaken_for_a_study(tmp_path):
    import sqlite3

    path = tmp_path / "other.db"
    with sqlite3.connect(path) as conn:
        conn.execute("CREATE TABLE customers (id INTEGER)")
    with pytest.raises(SchemaVersionError, match="not a studyctl database"):
        Database.open(path)


def test_corrupted_file_is_one_clear_error(tmp_path):
    path = tmp_path / "study.db"
    path.write_bytes(b"this is not a database at all" * 200)
    with pytest.raises(StoreError, match="not a readable SQLite study database") as err:
        Database.open(path)
    assert "\n" not in str(err.value)


def test_missing_file_is_not_created(tmp_path):
    path = tmp_path / "nope.db"
    with pytest.raises(StoreError, match="no study database"):
        Database.open(path)
    assert not path.exists()


@pytest.mark.parametrize("table", ["event", "audit_log"])
def test_append_only_tables_refuse_update_and_delete(store, table):
    study = store.create_study("s")
    p = store.add_participant(study.id, "P1")
    sess = store.start_session(p.id)
    store.append_event(sess.id, "start", {}, t_mono=0.0)
    for sql in (f"UPDATE {table} SET id = id", f"DELETE FROM {table}"):
        with pytest.raises(Exception, match="append-only"), store.db.engine.begin() as conn:
            conn.execute(text(sql))


def test_sqlite_connection_settings(sqlite_store):
    with sqlite_store.db.engine.connect() as conn:
        assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
        assert conn.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
        assert conn.exec_driver_sql("PRAGMA synchronous").scalar() == 2  # FULL
        assert conn.exec_driver_sql("PRAGMA busy_timeout").scalar() >= 10_000
