"""Shared fixtures.

Database fixtures (any test folder may use them):

- ``db_url``: a fresh, empty study database at schema head, parametrized over SQLite and PostgreSQL
  (so a test using it runs twice); ``store``: a :class:`~studyctl.store.StudyStore` open on it.
- ``sqlite_url`` / ``sqlite_store``: the same on SQLite only.
- ``pg_url`` / ``pg_store``: the same on PostgreSQL only.
- ``isolated_db_url``: a fresh database of its own at schema head (both backends; slower on PostgreSQL,
  ~1 s): for tests that change the schema (downgrade, stamp, DDL).
- ``empty_db_url``: a database with no schema at all (both backends), for migration tests.
- ``pg_server``: the throwaway PostgreSQL server (initdb into a temp folder, loopback only, started
  once per test session on first use; as root it runs as the ``postgres`` user). It is never skipped:
  when PostgreSQL's binaries are missing the fixture errors and says how to install them
  (``bash scripts/ensure-postgres.sh``).

Fresh SQLite databases are copies of one template migrated once per session. On PostgreSQL,
``pg_url`` reuses one database migrated once per session and empties it before each test (other
connections to it are terminated, every table truncated, identities restarted), because
``CREATE DATABASE`` costs about a second. So: close your stores, and never change the schema of a
``pg_url``/``db_url`` database; use ``isolated_db_url`` for that.
"""

from __future__ import annotations

import itertools
import os
import shutil

import pytest

# headless figures; set for matplotlib's first import (by a test), so collection does not import it
os.environ["MPLBACKEND"] = "Agg"

_counter = itertools.count()


# Markers that follow from the fixtures a test uses, so a new test cannot slip into the fast default run
# (pyproject: plain `pytest` deselects slow, browser and postgres; `pytest -m ""`, as CI runs it, selects all).
_MARK_BY_FIXTURE = {"new_browser": "browser", "pg_server": "postgres"}


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects
def pytest_collection_modifyitems(items):
    for item in items:
        for fixture in set(_MARK_BY_FIXTURE).intersection(getattr(item, "fixturenames", ())):
            item.add_marker(getattr(pytest.mark, _MARK_BY_FIXTURE[fixture]))


@pytest.fixture(autouse=True)
def _audit_head_dir(tmp_path_factory, monkeypatch):
    """Each test keeps PostgreSQL audit head files in a folder of its own: the shared test database is
    emptied between tests, which to a head file kept across tests looks exactly like a rewritten log."""
    monkeypatch.setenv("STUDYCTL_AUDIT_HEAD_DIR", str(tmp_path_factory.mktemp("audit-heads")))


@pytest.fixture
def pty_workspace(tmp_path):
    """A workspace of the engine's small terminal-test study (palpation, grid reports, 2 conditions) with PTY-AAAAA
    enrolled, made in a fresh process, and the environment for running ``studyctl`` on a terminal in it."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    protocol = Path(__file__).parent / "engine" / "data" / "pty_protocol.yaml"
    ws = tmp_path / "ws"
    env = {k: v for k, v in os.environ.items() if k != "STUDYCTL_DB"}
    script = (
        "from studyctl.store.workspace import init_workspace, open_study\n"
        "from studyctl.store.enrollment import enroll\n"
        f"init_workspace({str(ws)!r}, protocol={str(protocol)!r})\n"
        f"with open_study(workspace={str(ws)!r}) as o:\n"
        "    enroll(o.store, code='PTY-AAAAA')\n"
    )
    subprocess.run([sys.executable, "-c", script], check=True, env=env, timeout=120)
    env.update(TERM="xterm", COLUMNS="120", LINES="40")
    return ws, env


@pytest.fixture(scope="session")
def pg_server():
    """The session's throwaway PostgreSQL server (a :class:`studyctl.store.pgserver.ThrowawayPostgres`)."""
    from studyctl.store.pgserver import ThrowawayPostgres

    server = ThrowawayPostgres(fsync=False).start()
    yield server
    server.stop()


@pytest.fixture(scope="session")
def _sqlite_template(tmp_path_factory):
    from studyctl.store.db import Database

    path = tmp_path_factory.mktemp("sqlite-template") / "template.db"
    Database.create(path).close()
    return path


@pytest.fixture(scope="session")
def _pg_shared(pg_server):
    from studyctl.store.db import Database

    url = pg_server.create_database("studyctl_shared")
    Database.create(url).close()
    return url


def _reset_pg(pg_server) -> None:
    import psycopg

    from studyctl.store.audit import GENESIS_HASH
    from studyctl.store.models import Base

    tables = ", ".join(f'"{t}"' for t in Base.metadata.tables)
    with psycopg.connect(host="127.0.0.1", port=pg_server.port, user="postgres", dbname="studyctl_shared",
                         autocommit=True) as conn:
        conn.execute("SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                     "WHERE datname = current_database() AND pid <> pg_backend_pid()")
        conn.execute(f"TRUNCATE {tables} RESTART IDENTITY CASCADE")
        for table in ("event", "audit_log"):  # in case a test disabled the append-only triggers
            conn.execute(f"ALTER TABLE {table} ENABLE TRIGGER USER")
        conn.execute("INSERT INTO audit_head (id, count, hash) VALUES (1, 0, %s)", (GENESIS_HASH,))


@pytest.fixture(scope="session")
def _pg_template(pg_server):
    from studyctl.store.db import Database

    Database.create(pg_server.create_database("studyctl_template")).close()
    return "studyctl_template"


def _fresh_sqlite(template, tmp_path) -> str:
    target = tmp_path / f"study-{next(_counter)}.db"
    shutil.copyfile(template, target)
    target.chmod(0o600)
    return f"sqlite:///{target}"


def _fresh_pg(pg_server, template: str | None) -> str:
    return pg_server.create_database(f"test_{next(_counter)}", template=template)


@pytest.fixture
def sqlite_url(_sqlite_template, tmp_path) -> str:
    """URL of a fresh SQLite study database at schema head."""
    return _fresh_sqlite(_sqlite_template, tmp_path)


@pytest.fixture
def pg_url(pg_server, _pg_shared) -> str:
    """URL of an empty PostgreSQL study database at schema head (emptied before each test)."""
    _reset_pg(pg_server)
    return _pg_shared


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def db_url(request) -> str:
    """URL of a fresh study database at schema head, once on SQLite and once on PostgreSQL."""
    return request.getfixturevalue("sqlite_url" if request.param == "sqlite" else "pg_url")


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def isolated_db_url(request, tmp_path) -> str:
    """URL of a new database of its own at schema head (safe to downgrade, stamp or alter)."""
    if request.param == "sqlite":
        return _fresh_sqlite(request.getfixturevalue("_sqlite_template"), tmp_path)
    return _fresh_pg(request.getfixturevalue("pg_server"), request.getfixturevalue("_pg_template"))


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def empty_db_url(request, tmp_path) -> str:
    """URL of a database without any schema (SQLite: a path that does not exist yet)."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / f'empty-{next(_counter)}.db'}"
    return _fresh_pg(request.getfixturevalue("pg_server"), None)


def _open(url):
    from studyctl.store import StudyStore

    return StudyStore.open(url)


@pytest.fixture
def store(db_url):
    """A StudyStore on a fresh database (SQLite and PostgreSQL)."""
    s = _open(db_url)
    yield s
    s.close()


@pytest.fixture
def sqlite_store(sqlite_url):
    s = _open(sqlite_url)
    yield s
    s.close()


@pytest.fixture
def pg_store(pg_url):
    s = _open(pg_url)
    yield s
    s.close()
