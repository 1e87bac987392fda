"""A throwaway PostgreSQL server for tests and benchmarks: initdb into a temp folder, loopback only.

PostgreSQL refuses to run as root, so when studyctl runs as root the server runs as the ``postgres``
system user (created by Debian's ``postgresql`` package; created here if missing) through ``runuser``.
The server listens on 127.0.0.1 at a free port with no Unix socket, trusts local TCP connections (it
holds only test data and disappears on :meth:`ThrowawayPostgres.stop`).

``scripts/ensure-postgres.sh`` installs the server binaries where they are missing.
"""

from __future__ import annotations

import atexit
import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from studyctl.errors import StoreError

RUN_AS_WHEN_ROOT = "postgres"


def find_pg_binary(name: str) -> Path:
    """Path of a PostgreSQL server program (``initdb``, ``pg_ctl``), newest installed version first."""
    on_path = shutil.which(name)
    if on_path:
        return Path(on_path)
    candidates = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"),
                        key=lambda p: int(Path(p).parts[-3]) if Path(p).parts[-3].isdigit() else 0)
    if candidates:
        return Path(candidates[-1])
    raise StoreError(f"PostgreSQL's {name} is not installed; run `bash scripts/ensure-postgres.sh` "
                     "(or `apt-get install postgresql`)")


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _ensure_user(name: str) -> pwd.struct_passwd:
    try:
        return pwd.getpwnam(name)
    except KeyError:
        subprocess.run(["useradd", "--system", "--no-create-home", "--shell", "/usr/sbin/nologin", name],
                       check=True, capture_output=True)
        return pwd.getpwnam(name)


class ThrowawayPostgres:
    """Start a private PostgreSQL server; :attr:`url` connects to its ``postgres`` database.

    Parameters
    ----------
    fsync : bool
        Keep PostgreSQL's fsync on (benchmarks measuring durable writes) or off (faster tests).
    """

    def __init__(self, *, fsync: bool = False) -> None:
        self.fsync = fsync
        self.port: int | None = None
        self.datadir: Path | None = None
        self._as_root = os.geteuid() == 0
        self._proc_user: pwd.struct_passwd | None = None

    # -- helpers ----------------------------------------------------------------------------------
    def _run(self, args: list[str], timeout: float = 120) -> subprocess.CompletedProcess[str]:
        cmd = [str(a) for a in args]
        if self._as_root:
            cmd = ["runuser", "-u", RUN_AS_WHEN_ROOT, "--", *cmd]
        env = {**os.environ, "LC_ALL": "C", "LANG": "C"}
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd="/")

    @property
    def url(self) -> str:
        return self.database_url("postgres")

    def database_url(self, name: str) -> str:
        """URL of database ``name`` on this server."""
        if self.port is None:
            raise StoreError("the throwaway PostgreSQL server is not running")
        return f"postgresql+psycopg://postgres@127.0.0.1:{self.port}/{name}"

    # -- lifecycle --------------------------------------------------------------------------------
    def start(self) -> ThrowawayPostgres:
        initdb, pg_ctl = find_pg_binary("initdb"), find_pg_binary("pg_ctl")
        # As root the server runs as another user, who must reach the folder: /tmp, not a private TMPDIR.
        base = "/tmp" if self._as_root and Path("/tmp").is_dir() else None
        self.datadir = Path(tempfile.mkdtemp(prefix="studyctl-pg-", dir=base))
        if self._as_root:
            user = _ensure_user(RUN_AS_WHEN_ROOT)
            os.chown(self.datadir, user.pw_uid, user.pw_gid)
        os.chmod(self.datadir, 0o700)
        data = self.datadir / "data"
        out = self._run([initdb, "-D", data, "-U", "postgres", "-A", "trust", "-E", "UTF8", "--locale=C",
                         "--no-sync"])
        if out.returncode != 0:
            self._cleanup()
            raise StoreError(f"initdb failed: {(out.stderr or out.stdout).strip()[-500:]}")
        last_err = ""
        for _ in range(5):
            self.port = _free_port()
            options = (f"-c listen_addresses=127.0.0.1 -p {self.port} -c unix_socket_directories='' "
                       f"-c fsync={'on' if self.fsync else 'off'} -c max_connections=60 "
                       "-c shared_buffers=64MB")
            if not self.fsync:
                options += " -c synchronous_commit=off -c full_page_writes=off"
            out = self._run([pg_ctl, "-D", data, "-o", options, "-l", self.datadir / "server.log", "-w",
                             "-t", "60", "start"])
            if out.returncode == 0:
                atexit.register(self.stop)
                return self
            last_err = (out.stderr or out.stdout).strip()
            log = self.datadir / "server.log"
            if log.exists():
                last_err += " | " + log.read_text(errors="replace")[-400:]
        self._cleanup()
        raise StoreError(f"could not start the throwaway PostgreSQL server: {last_err[-800:]}")

    def stop(self) -> None:
        """Stop the server (immediate) and delete its data folder."""
        if self.datadir is None:
            return
        data = self.datadir / "data"
        if (data / "postmaster.pid").exists():
            self._run([find_pg_binary("pg_ctl"), "-D", data, "-m", "immediate", "-w", "stop"], timeout=60)
        self._cleanup()

    def _cleanup(self) -> None:
        if self.datadir is not None:
            shutil.rmtree(self.datadir, ignore_errors=True)
        self.datadir = None
        self.port = None

    def __enter__(self) -> ThrowawayPostgres:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- databases --------------------------------------------------------------------------------
    def create_database(self, name: str, template: str | None = None) -> str:
        """Create database ``name`` (optionally as a copy of ``template``) and return its URL."""
        import psycopg

        if not name.replace("_", "").isalnum():
            raise StoreError(f"database name {name!r} must be letters, digits and underscores")
        sql = f'CREATE DATABASE "{name}"' + (f' TEMPLATE "{template}"' if template else "")
        deadline = time.monotonic() + 30
        while True:
            try:
                with psycopg.connect(host="127.0.0.1", port=self.port, user="postgres", dbname="postgres",
                                     autocommit=True, connect_timeout=10) as conn:
                    conn.execute(sql)
                return self.database_url(name)
            except psycopg.errors.ObjectInUse:
                # The template still has a connection closing; retry briefly.
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)


__all__ = ["ThrowawayPostgres", "find_pg_binary"]
