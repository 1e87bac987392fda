"""Study workspaces: a folder with ``studyctl.toml`` and (by default) the SQLite database ``study.db``.

``studyctl init DIR`` creates one with :func:`init_workspace`; every other command finds its database
with :func:`resolve_database`: ``--db URL`` first, then ``STUDYCTL_DB``, then the workspace's
``studyctl.toml`` (``--workspace DIR``, default the current folder).

A PostgreSQL workspace stores its URL without the password; libpq reads it from ``PGPASSWORD`` or
``~/.pgpass`` (or pass the full URL through ``STUDYCTL_DB``).
"""

from __future__ import annotations

import contextlib
import json
import os
import tomllib
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from sqlalchemy import URL

from studyctl import __version__
from studyctl.closing import Closeable
from studyctl.errors import ConfigError, StoreError, StudyctlError, UsageError
from studyctl.protocol import Protocol, load_protocol, resolve_protocol
from studyctl.store.db import Database, describe_url, parse_url, require_head
from studyctl.store.models import Study
from studyctl.store.repository import StudyStore, check_text

WORKSPACE_FILE = "studyctl.toml"
DB_FILE = "study.db"
ENV_DB = "STUDYCTL_DB"


@dataclass(frozen=True)
class Workspace:
    """A study workspace folder as described by its ``studyctl.toml``."""

    root: Path
    study: str
    database: str  # a path relative to root, or a URL without password

    @property
    def url(self) -> URL:
        if "://" in self.database:
            return parse_url(self.database)
        return parse_url(str((self.root / self.database).resolve()))


def load_workspace(root: str | os.PathLike[str]) -> Workspace:
    """Read ``root/studyctl.toml``; :class:`ConfigError` names the file and the problem."""
    folder = Path(root)
    file = folder / WORKSPACE_FILE
    if not file.is_file():
        raise ConfigError(f"{folder} is not a studyctl workspace (no {WORKSPACE_FILE}); create one with "
                          f"`studyctl init {folder}` or pass --workspace / --db")
    try:
        data = tomllib.loads(file.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{file}: not valid TOML ({exc}); fix the file or re-create the workspace") from None
    except OSError as exc:
        raise ConfigError(f"cannot read {file}: {exc.strerror}") from None
    study = data.get("study", {}).get("name") if isinstance(data.get("study"), dict) else None
    database = data.get("database", {}).get("url") if isinstance(data.get("database"), dict) else None
    for key, value in (("[study] name", study), ("[database] url", database)):
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{file}: {key} is missing or not a string; expected e.g. "
                              '[study] name = "my-study" and [database] url = "study.db"')
    return Workspace(root=folder, study=study, database=database)


def find_workspace(start: str | os.PathLike[str] | None = None) -> Workspace | None:
    """The workspace in ``start`` (default the current folder), or None if there is none."""
    folder = Path(start) if start is not None else Path.cwd()
    if (folder / WORKSPACE_FILE).is_file():
        return load_workspace(folder)
    return None


def resolve_database(
    db: str | None = None, workspace: str | os.PathLike[str] | None = None
) -> tuple[URL, Workspace | None]:
    """Which database a command uses: ``db`` (``--db``), then ``$STUDYCTL_DB``, then the workspace."""
    ws = load_workspace(workspace) if workspace is not None else None
    if db is not None:
        if not str(db).strip():
            # an empty --db (e.g. an unset shell variable) must not silently fall back to the workspace
            raise ConfigError("--db is empty; give a database URL (sqlite:///PATH, a file path or "
                              f"postgresql://USER@HOST:PORT/DBNAME), or leave --db out to use {ENV_DB} or the "
                              "workspace")
        return parse_url(db), ws
    env = os.environ.get(ENV_DB, "").strip()
    if env:
        return parse_url(env), ws
    if ws is None:
        ws = find_workspace()
    if ws is None:
        raise ConfigError(f"no study database given: run inside a workspace (a folder with {WORKSPACE_FILE}), "
                          f"or pass --workspace DIR, --db URL or set {ENV_DB}")
    return ws.url, ws


@dataclass
class OpenStudy(Closeable):
    """A store opened for one study (close it, or use it as a context manager)."""

    store: StudyStore
    study: Study
    workspace: Workspace | None

    def close(self) -> None:
        self.store.close()


def open_study(
    db: str | None = None, workspace: str | os.PathLike[str] | None = None, study: str | None = None
) -> OpenStudy:
    """Open the database a command should use and look up its study.

    The study is ``study`` if given, else the workspace's study, else the only study in the database.
    """
    url, ws = resolve_database(db, workspace)
    store = StudyStore.open(url)
    try:
        name = study or (ws.study if ws is not None else None)
        return OpenStudy(store=store, study=store.get_study(name), workspace=ws)
    except BaseException:
        store.close()
        raise


# ------------------------------------------------------------------------------------------- init


@dataclass(frozen=True)
class InitResult:
    """What :func:`init_workspace` created."""

    root: Path
    study: str
    database: str
    protocol_name: str | None
    protocol_sha256: str | None
    seed: int


def _toml_str(value: str) -> str:
    return json.dumps(value)  # a JSON string is a valid TOML basic string


def _workspace_text(study: str, database: str) -> str:
    return (
        "# studyctl workspace: which study this folder belongs to and where its data live.\n"
        f"# Created {datetime.now(UTC).isoformat(timespec='seconds')} by studyctl {__version__}.\n\n"
        f"[study]\nname = {_toml_str(study)}\n\n"
        f"[database]\n# A file relative to this folder, or postgresql://USER@HOST:PORT/DB (password from PGPASSWORD)\n"
        f"url = {_toml_str(database)}\n"
    )


def _load_protocol(protocol: str | Protocol) -> tuple[str, str, str | None, int | None]:
    """(text, name, study id, seed) of a protocol given loaded, or by shipped name or file path (validated here)."""
    model = protocol if isinstance(protocol, Protocol) else load_protocol(resolve_protocol(protocol))
    return model.source_text, Path(model.path).stem, model.study.id, model.study.seed


def _link_new(src: Path, dst: Path) -> None:
    """Move ``src`` to ``dst`` atomically, failing if ``dst`` already exists (no silent overwrite)."""
    try:
        os.link(src, dst)
    except FileExistsError:
        raise UsageError(f"{dst} appeared while initialising; another `studyctl init` runs here?") from None
    src.unlink()


def check_new_workspace(folder: Path, db: str | None) -> URL | None:
    """Check that ``folder`` can hold a new study and ``db`` is a usable ``--db``; return the parsed URL or None.

    Callers that show progress (``simulate``) call it first, so a bad folder or ``--db`` is one Error line
    before anything is displayed or written.
    """
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"{folder} is a file, not a folder; choose a folder for the workspace")
    for marker in (WORKSPACE_FILE, DB_FILE):
        if (folder / marker).exists():
            raise UsageError(f"{folder} already holds a study ({marker} exists); choose an empty or new folder, "
                             "or work in the existing study")
    if db is not None and not str(db).strip():
        raise ConfigError("--db is empty; give a PostgreSQL URL (postgresql://USER@HOST:PORT/DBNAME), or leave --db "
                          "out for a SQLite study.db in the workspace")
    url = parse_url(db) if db else None
    if url is not None and url.get_backend_name() == "sqlite":
        # A SQLite study always lives in the workspace folder (the audit head file and the locks sit beside it).
        raise UsageError(f"--db {db}: --db takes a PostgreSQL URL (postgresql://USER@HOST:PORT/DBNAME); a SQLite "
                         f"study lives in the workspace as {DB_FILE}: leave --db out")
    return url


def init_workspace(
    root: str | os.PathLike[str],
    *,
    protocol: str | Protocol | None = None,
    name: str | None = None,
    db: str | None = None,
    seed: int | None = None,
) -> InitResult:
    """Create a study workspace in ``root``: ``studyctl.toml`` plus a database at schema head.

    Parameters
    ----------
    root : path
        The folder (created if missing; may exist if it holds no study).
    protocol : str, optional
        A shipped protocol name or a protocol file; validated, and its exact text and sha256 stored.
    name : str, optional
        The study's name; default the protocol's study id, else the folder name.
    db : str, optional
        A PostgreSQL URL to use instead of a new ``study.db`` in the folder.
    seed : int, optional
        The study's master seed; default the protocol's seed, else 63 random bits.

    Nothing is left behind when it fails: the temporary database and any folder it created are removed.
    """
    folder = Path(root).expanduser()
    url = check_new_workspace(folder, db)
    text = proto_name = proto_study = None
    proto_seed = None
    if protocol is not None:
        text, proto_name, proto_study, proto_seed = _load_protocol(protocol)
    study_name = check_text(name or proto_study or folder.resolve().name or "study", "study name")

    created_dir = False
    temps: list[Path] = []
    try:
        if not folder.exists():
            try:
                folder.mkdir(parents=True, mode=0o700)
            except OSError as exc:
                raise StoreError(f"cannot create folder {folder}: {exc.strerror}; choose a writable location") from None
            created_dir = True
        toml_tmp = folder / f".{WORKSPACE_FILE}.init-{os.getpid()}"
        if url is None:
            db_tmp = folder / f".{DB_FILE}.init-{os.getpid()}"
            temps += [toml_tmp, db_tmp]
            _write_private(toml_tmp, _workspace_text(study_name, DB_FILE))
            with contextlib.closing(StudyStore.create(db_tmp)) as store:
                study = store.create_study(study_name, protocol_text=text, protocol_name=proto_name,
                                           seed=seed if seed is not None else proto_seed)
            # The store is closed: SQLite has checkpointed and removed the -wal/-shm files.
            _link_new(db_tmp, folder / DB_FILE)
            temps.append(folder / DB_FILE)  # remove it too if the last step fails
            head_tmp = Path(f"{db_tmp}.head")  # the audit head file follows its database (store.anchor)
            if head_tmp.exists():
                os.replace(head_tmp, folder / f"{DB_FILE}.head")
            _link_new(toml_tmp, folder / WORKSPACE_FILE)
            database_desc = str(folder / DB_FILE)
        else:
            # Never write the password into the workspace: libpq reads it from PGPASSWORD or ~/.pgpass.
            stored_url = url._replace(password=None).render_as_string(hide_password=False)
            temps.append(toml_tmp)
            _write_private(toml_tmp, _workspace_text(study_name, stored_url))
            with contextlib.closing(_open_or_migrate(url)) as store:
                study = store.create_study(study_name, protocol_text=text, protocol_name=proto_name,
                                           seed=seed if seed is not None else proto_seed)
            _link_new(toml_tmp, folder / WORKSPACE_FILE)
            database_desc = describe_url(url)
        temps.clear()
    except BaseException as exc:
        for path in temps:
            for suffix in ("", "-wal", "-shm", "-journal", ".head"):
                Path(f"{path}{suffix}").unlink(missing_ok=True)
        if created_dir:
            with contextlib.suppress(OSError):
                folder.rmdir()
        if isinstance(exc, OSError) and not isinstance(exc, StudyctlError):
            raise StoreError(f"cannot write the workspace in {folder}: {exc.strerror or exc}; "
                             "check the folder is writable and has free space") from None
        raise
    return InitResult(root=folder, study=study.name, database=database_desc, protocol_name=proto_name,
                      protocol_sha256=study.protocol_sha256, seed=study.seed)


def _write_private(path: Path, text: str) -> None:
    fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())


def _open_or_migrate(url: URL) -> StudyStore:
    """Open a PostgreSQL database for a new study, migrating it first if it is empty."""
    db = Database.open(url, check_schema=False)
    try:
        state = db.schema_state()
        if state.current is None and not state.has_tables:
            db.upgrade()
        else:
            require_head(state, db.describe())
    except BaseException:
        db.close()
        raise
    return StudyStore(db)


__all__ = [
    "DB_FILE",
    "ENV_DB",
    "WORKSPACE_FILE",
    "InitResult",
    "OpenStudy",
    "Workspace",
    "find_workspace",
    "init_workspace",
    "load_workspace",
    "open_study",
    "resolve_database",
]
