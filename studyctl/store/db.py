"""Open a study database (SQLite file or PostgreSQL URL), check or upgrade its schema, run transactions.

SQLite connections run in WAL mode with foreign keys on and a busy timeout. Commits are fsynced
(``synchronous=FULL``: a committed trial survives a power cut) except the frequent small commits inside
a trial (sample flushes, events: ``in_transaction(durable=False)``), which survive the process being
killed and become power-safe with the next durable commit. Write transactions start with
``BEGIN IMMEDIATE`` so concurrent writers queue on the busy timeout instead of failing on a lock
upgrade. PostgreSQL connects through psycopg 3; :meth:`Database.in_transaction` can
take a named advisory lock to serialise e.g. concurrent enrollers across sites.

Migrations are configured in code from the shipped ``migrations/`` folder
(:func:`studyctl.resources.resource_dir`), so an installed wheel needs no alembic.ini.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import URL, Connection, Engine, create_engine, event, inspect, text
from sqlalchemy import exc as sa_exc
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

from studyctl.closing import Closeable
from studyctl.errors import ConfigError, SchemaVersionError, StoreError, UsageError
from studyctl.resources import resource_dir

BUSY_TIMEOUT_MS = 30_000
PG_CONNECT_TIMEOUT_S = 5
_SUPPORTED = "sqlite:///PATH, a plain file path, or postgresql://USER@HOST:PORT/DBNAME"


# --------------------------------------------------------------------------------------------- URLs


def parse_url(url: str | os.PathLike[str] | URL) -> URL:
    """Turn a database URL or a plain SQLite file path into a SQLAlchemy URL.

    ``postgres://`` and ``postgresql://`` select the psycopg 3 driver. Raises :class:`ConfigError`
    naming the value and the accepted forms when the URL is malformed or of an unsupported kind.
    """
    if isinstance(url, URL):
        parsed = url
    else:
        raw = os.fspath(url).strip()
        if not raw:
            raise ConfigError(f"empty database URL; use {_SUPPORTED}")
        if "://" not in raw and not raw.startswith("sqlite:"):
            return URL.create("sqlite", database=str(Path(raw).expanduser()))
        try:
            parsed = make_url(raw)
        except (sa_exc.ArgumentError, ValueError) as exc:
            raise ConfigError(f"malformed database URL {_mask(raw)!r}: {exc}; use {_SUPPORTED}") from None
    backend = parsed.get_backend_name()
    if backend == "postgres":
        parsed = parsed.set(drivername="postgresql+psycopg")
    elif backend == "postgresql":
        if parsed.get_driver_name() not in ("psycopg", "psycopg2", ""):
            raise ConfigError(f"database URL {describe_url(parsed)!r} uses driver {parsed.get_driver_name()!r}; "
                              "studyctl talks to PostgreSQL through psycopg 3: use postgresql://…")
        parsed = parsed.set(drivername="postgresql+psycopg")
        if not parsed.database:
            raise ConfigError(f"database URL {describe_url(parsed)!r} names no database; "
                              "add one: postgresql://USER@HOST:PORT/DBNAME")
    elif backend == "sqlite":
        if parsed.database in (None, "") and parsed.drivername == "sqlite":
            parsed = parsed.set(database=":memory:")
    else:
        raise ConfigError(f"unsupported database {backend!r} in URL {describe_url(parsed)!r}; use {_SUPPORTED}")
    return parsed


def _mask(raw: str) -> str:
    try:
        return make_url(raw).render_as_string(hide_password=True)
    except Exception:
        return raw.split("@")[-1] if "@" in raw else raw


def describe_url(url: URL | str) -> str:
    """The URL as safe to print: the password replaced by ``***``."""
    if isinstance(url, str):
        return _mask(url)
    return url.render_as_string(hide_password=True)


def is_sqlite(url: URL) -> bool:
    return url.get_backend_name() == "sqlite"


def sqlite_path(url: URL) -> Path | None:
    """The file of a SQLite URL, or None for an in-memory database."""
    if not is_sqlite(url) or url.database in (None, "", ":memory:"):
        return None
    return Path(url.database)


# ------------------------------------------------------------------------------------------ engines


def create_db_engine(url: URL, *, must_exist: bool = True) -> Engine:
    """A SQLAlchemy engine for ``url`` with studyctl's connection settings.

    ``must_exist`` refuses to create a new SQLite file (SQLite would silently create an empty one).
    """
    if is_sqlite(url):
        path = sqlite_path(url)
        if path is not None and must_exist and not path.is_file():
            raise StoreError(f"no study database at {path}; create a workspace with `studyctl init DIR` "
                             "or point --db / STUDYCTL_DB at an existing one")
        engine = create_engine(url, connect_args={"timeout": BUSY_TIMEOUT_MS / 1000})
        event.listen(engine, "connect", _sqlite_on_connect)
        event.listen(engine, "begin", _sqlite_on_begin)
        return engine
    return create_engine(
        url,
        connect_args={"connect_timeout": PG_CONNECT_TIMEOUT_S, "application_name": "studyctl"},
        pool_pre_ping=True,
    )


SQLITE_PAGE_SIZE = 65536


def _format_sqlite(path: Path) -> None:
    """Give a new, empty SQLite file its page size (fixed once the file holds data) and WAL mode.

    64 KiB pages: a 1 s sample chunk (128 KiB) then spans 2 overflow pages instead of 32, which reads a
    90 s trial back ~5× faster (see ``studyctl bench store``); small commits cost about the same.
    """
    import sqlite3

    try:
        conn = sqlite3.connect(path)
        try:
            conn.execute(f"PRAGMA page_size = {SQLITE_PAGE_SIZE}")
            conn.execute("PRAGMA journal_mode = WAL")
        finally:
            conn.close()
    except sqlite3.Error as exc:
        raise StoreError(f"cannot initialise SQLite database {path}: {exc}") from None


def _sqlite_on_connect(dbapi_connection: Any, _record: Any) -> None:
    # Take over transaction control from the sqlite3 module so BEGIN IMMEDIATE is possible.
    dbapi_connection.isolation_level = None
    cur = dbapi_connection.cursor()
    try:
        cur.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        cur.execute("PRAGMA foreign_keys = ON")
        mode = cur.execute("PRAGMA journal_mode").fetchone()[0]
        if mode != "memory" and mode != "wal":
            cur.execute("PRAGMA journal_mode = WAL")
        cur.execute("PRAGMA synchronous = FULL")
    finally:
        cur.close()


def _sqlite_on_begin(conn: Connection) -> None:
    options = conn.get_execution_options()
    # synchronous is per connection and must be set outside a transaction: set it for this one.
    conn.exec_driver_sql(f"PRAGMA synchronous = {options.get('studyctl_sync', 'FULL')}")
    conn.exec_driver_sql(f"BEGIN {options.get('studyctl_begin', 'DEFERRED')}")


def _translate(exc: BaseException, url: URL) -> StoreError:
    """One clear line for a low-level database error."""
    msg = str(getattr(exc, "orig", exc)).strip().splitlines()[0] if str(getattr(exc, "orig", exc)).strip() else ""
    where = describe_url(url)
    if is_sqlite(url):
        path = sqlite_path(url)
        lowered = msg.lower()
        if "not a database" in lowered or "malformed" in lowered or "corrupt" in lowered:
            return StoreError(f"{path} is not a readable SQLite study database ({msg}); it is damaged or "
                              "not a studyctl file: restore it from a backup or copy")
        if "readonly" in lowered or "read-only" in lowered or "unable to open" in lowered:
            return StoreError(f"cannot write {path} ({msg}); check the file and folder permissions")
        if "locked" in lowered or "busy" in lowered:
            return StoreError(f"{path} stayed locked by another studyctl process for {BUSY_TIMEOUT_MS // 1000} s "
                              f"({msg}); wait for it to finish or stop it, then retry")
        return StoreError(f"SQLite error on {path}: {msg}")
    if isinstance(exc, sa_exc.OperationalError) and ("connect" in msg.lower() or "connection" in msg.lower()):
        return StoreError(f"cannot connect to PostgreSQL at {where} ({msg}); check that the server runs, "
                          "the host/port/user/database in the URL, and the network")
    return StoreError(f"database error on {where}: {msg}")


# ----------------------------------------------------------------------------------------- alembic


def alembic_config(connection: Connection | None = None, url: URL | None = None) -> Config:
    """An alembic Config built in code from the shipped migrations folder."""
    cfg = Config()
    cfg.set_main_option("script_location", str(resource_dir("migrations")))
    if url is not None:
        cfg.set_main_option("sqlalchemy.url", url.render_as_string(hide_password=False).replace("%", "%%"))
    if connection is not None:
        cfg.attributes["connection"] = connection
    return cfg


def head_revision() -> str:
    """The newest schema revision this studyctl knows."""
    heads = ScriptDirectory.from_config(alembic_config()).get_heads()
    if len(heads) != 1:
        raise SchemaVersionError(f"studyctl's migrations have {len(heads)} heads ({', '.join(heads)}); "
                                 "this installation is broken: reinstall studyctl")
    return heads[0]


def known_revisions() -> set[str]:
    return {rev.revision for rev in ScriptDirectory.from_config(alembic_config()).walk_revisions()}


@dataclass(frozen=True)
class SchemaState:
    """Where a database's schema stands relative to this studyctl."""

    current: str | None
    head: str
    has_tables: bool

    @property
    def up_to_date(self) -> bool:
        return self.current == self.head


def schema_state(engine: Engine) -> SchemaState:
    """Read the database's alembic revision (None when it was never migrated)."""
    with engine.connect() as conn:
        current = MigrationContext.configure(conn).get_current_revision()
        has_tables = bool(set(inspect(conn).get_table_names()) - {"alembic_version"})
    return SchemaState(current=current, head=head_revision(), has_tables=has_tables)


def require_head(state: SchemaState, where: str) -> None:
    """Raise :class:`SchemaVersionError` with what to do unless the schema is at this studyctl's head."""
    if state.up_to_date:
        return
    if state.current is None:
        if state.has_tables:
            raise SchemaVersionError(f"{where} holds tables but no studyctl schema revision; it is not a "
                                     "studyctl database: point --db at a study database or create one with "
                                     "`studyctl init DIR`")
        raise SchemaVersionError(f"{where} has no studyctl schema yet; run `studyctl db upgrade` "
                                 "(or create a workspace with `studyctl init DIR`)")
    if state.current not in known_revisions():
        raise SchemaVersionError(f"{where} is at schema revision {state.current}, which this studyctl "
                                 f"(head {state.head}) does not know: it was written by a newer studyctl; "
                                 "upgrade studyctl (pip install -U studyctl) to open it")
    raise SchemaVersionError(f"{where} is at schema revision {state.current}, older than this studyctl's "
                             f"{state.head}; back it up, then run `studyctl db upgrade`")


# --------------------------------------------------------------------------------------- Database


class Database(Closeable):
    """An open study database: engine, session factory and transaction helpers.

    Use :meth:`open` (checks the schema is at head) or :meth:`create` (new database, migrated to head).
    """

    def __init__(self, engine: Engine, url: URL) -> None:
        self.engine = engine
        self.url = url
        self._sessions = sessionmaker(bind=engine, expire_on_commit=False)
        self._local = threading.local()

    # -- opening --------------------------------------------------------------------------------
    @classmethod
    def open(cls, url: str | os.PathLike[str] | URL, *, check_schema: bool = True) -> Database:
        """Open an existing database; raise :class:`SchemaVersionError` unless it is at head."""
        parsed = parse_url(url)
        engine = create_db_engine(parsed, must_exist=True)
        db = cls(engine, parsed)
        try:
            state = db.schema_state()
            if check_schema:
                require_head(state, db.describe())
        except BaseException:
            engine.dispose()
            raise
        return db

    @classmethod
    def create(cls, url: str | os.PathLike[str] | URL) -> Database:
        """Create (SQLite: a new file, mode 0600) and migrate a database to head."""
        parsed = parse_url(url)
        path = sqlite_path(parsed)
        if path is not None:
            if path.exists():
                raise StoreError(f"{path} already exists; refusing to overwrite a database")
            try:
                fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
            except OSError as exc:
                raise StoreError(f"cannot create {path}: {exc.strerror}; check the folder exists and is "
                                 "writable") from None
            os.close(fd)
            os.chmod(path, 0o600)
            _format_sqlite(path)
        engine = create_db_engine(parsed, must_exist=False)
        db = cls(engine, parsed)
        try:
            db.upgrade()
        except BaseException:
            engine.dispose()
            if path is not None:
                for suffix in ("", "-wal", "-shm", "-journal"):
                    Path(f"{path}{suffix}").unlink(missing_ok=True)
            raise
        return db

    def close(self) -> None:
        """Close every pooled connection (SQLite then checkpoints and removes its -wal/-shm files)."""
        self.engine.dispose()

    def describe(self) -> str:
        path = sqlite_path(self.url)
        return str(path) if path is not None else describe_url(self.url)

    @property
    def dialect(self) -> str:
        """``sqlite`` or ``postgresql``."""
        return self.engine.dialect.name

    # -- schema ---------------------------------------------------------------------------------
    def schema_state(self) -> SchemaState:
        try:
            return schema_state(self.engine)
        except sa_exc.DBAPIError as exc:
            raise _translate(exc, self.url) from None

    def upgrade(self, revision: str = "head") -> SchemaState:
        """Migrate the schema to ``revision`` (default the newest) in one transaction."""
        state = self.schema_state()
        if state.current is not None and state.current not in known_revisions():
            require_head(state, self.describe())
        try:
            with self.engine.begin() as conn:
                command.upgrade(alembic_config(connection=conn), revision)
        except sa_exc.DBAPIError as exc:
            raise _translate(exc, self.url) from None
        return self.schema_state()

    # -- transactions ---------------------------------------------------------------------------
    def session(self) -> Session:
        """A new ORM session (not yet in a transaction); prefer :meth:`in_transaction` / :meth:`reading`."""
        return self._sessions()

    @contextlib.contextmanager
    def in_transaction(self, lock: str | None = None, *, durable: bool = True) -> Iterator[Session]:
        """An ORM session in one write transaction, committed on success and rolled back on error.

        ``durable`` (default) makes the commit survive a power cut: SQLite fsyncs the WAL
        (``synchronous=FULL``), PostgreSQL waits for its WAL flush. ``durable=False`` is for frequent
        small commits inside a trial (sample flushes, events): they survive the studyctl process being
        killed (the data is in the WAL / on the server) but an operating-system crash may lose the
        commits since the last durable one, which the next durable commit (e.g. the trial's
        completion) makes permanent together with everything before it.

        On SQLite the transaction starts with ``BEGIN IMMEDIATE``: it holds the database's write lock
        from its first statement, so read-then-write logic (e.g. "find the next free slot, then take it")
        is atomic across processes. On PostgreSQL, ``lock`` names an advisory lock held until commit
        (``pg_advisory_xact_lock``) that serialises every transaction using the same name; on SQLite the
        write lock already does that and ``lock`` is ignored.
        """
        if getattr(self._local, "writing", False):
            # A second write transaction from the same thread would wait for the first one forever
            # (SQLite write lock, PostgreSQL row/advisory locks) or silently break atomicity.
            raise UsageError("a write transaction is already open on this database in this thread; pass its "
                             "session as tx= to the store call instead of opening another transaction")
        self._local.writing = True
        try:
            with self.engine.connect() as conn:
                if self.dialect == "sqlite":
                    conn.execution_options(studyctl_begin="IMMEDIATE", studyctl_sync="FULL" if durable else "NORMAL")
                with Session(bind=conn, expire_on_commit=False) as session, session.begin():
                    if self.dialect == "postgresql":
                        if not durable:
                            session.execute(text("SET LOCAL synchronous_commit TO off"))
                        if lock is not None:
                            session.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": advisory_key(lock)})
                    yield session
        except sa_exc.OperationalError as exc:
            raise _translate(exc, self.url) from None
        finally:
            self._local.writing = False

    @contextlib.contextmanager
    def reading(self) -> Iterator[Session]:
        """An ORM session in a read transaction (a consistent snapshot; never takes the write lock)."""
        try:
            with self._sessions() as session, session.begin():
                yield session
        except sa_exc.OperationalError as exc:
            raise _translate(exc, self.url) from None


def advisory_key(name: str) -> int:
    """A stable signed 64-bit key for ``pg_advisory_xact_lock`` from a lock name."""
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "big", signed=True)


__all__ = [
    "Database",
    "SchemaState",
    "advisory_key",
    "alembic_config",
    "create_db_engine",
    "describe_url",
    "head_revision",
    "parse_url",
    "require_head",
    "schema_state",
]
