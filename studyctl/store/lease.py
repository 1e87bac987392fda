"""One writer per session: a lease taken in the same transaction that starts or resumes a session.

The ``session_lease`` row names the process that may write the session (pid, host, since, heartbeat).
It is taken inside the write transaction that creates or resumes the session, so of any number of
processes starting the same session at once exactly one gets it; the others are refused with
``session N is being run by pid P on HOST since …``.

* SQLite: the transaction is ``BEGIN IMMEDIATE`` (one writer at a time), the row is the lease, and a
  heartbeat thread refreshes it every :data:`HEARTBEAT_S`. A row left behind by a killed process is
  recognised on the same host (its pid is gone), from another host once its heartbeat is older than
  :data:`STALE_S`; either way it is taken over only with ``--take-over`` (explicit, audited): a plain resume
  says who holds it, since when, and to use ``--take-over``.
* PostgreSQL: additionally a session-level advisory lock held on a connection of its own for the whole
  session. The server drops it when the owner's connection dies, so "is the owner alive?" has an exact
  answer there: the lock is held or it is not.

Every take-over of a lease left behind is written to the audit log (who had it, since when, why).
"""

from __future__ import annotations

import os
import secrets
import socket
import threading
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import bindparam, delete, select, text, update
from sqlalchemy.orm import Session as OrmSession

from studyctl.errors import SessionError
from studyctl.store.audit import append_audit
from studyctl.store.db import Database, advisory_key, is_sqlite, sqlite_path
from studyctl.store.models import SessionLease, utcnow

HEARTBEAT_S = 5.0
STALE_S = 30.0

# Checked at the start of every write transaction of a session (and in each sample flush): built once and run on
# the transaction's connection (Core), the same SELECT without ORM statement handling per check.
_LEASE_TOKEN = select(SessionLease.token).where(SessionLease.session_id == bindparam("session_id"))


@dataclass(frozen=True)
class LeaseHolder:
    """Who holds (or held) a session's lease, as stored."""

    session_id: int
    pid: int
    host: str
    since: datetime
    heartbeat_at: datetime

    def describe(self) -> str:
        return (f"session {self.session_id} is being run by pid {self.pid} on {self.host} since "
                f"{self.since:%Y-%m-%d %H:%M:%S} UTC")

    def refusal(self, extra: str = "") -> SessionError:
        return SessionError(f"{self.describe()}{extra}; if that process is gone, "
                            f"studyctl resume {self.session_id} --take-over")

    def left_behind(self, why: str) -> SessionError:
        """The refusal of a plain resume when the holder is provably gone: taking over is the coordinator's call."""
        return SessionError(f"session {self.session_id} is still held by pid {self.pid} on {self.host} since "
                            f"{self.since:%Y-%m-%d %H:%M:%S} UTC, which is gone ({why}); to continue the session"
                            f", take it over (audited): studyctl resume {self.session_id} --take-over")


def _holder(row: SessionLease) -> LeaseHolder:
    return LeaseHolder(int(row.session_id), int(row.pid), str(row.host), row.acquired_at, row.heartbeat_at)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def _lock_name(session_id: int) -> str:
    return f"studyctl-session-lease:{session_id}"


def current_holder(tx: OrmSession, session_id: int) -> LeaseHolder | None:
    row = tx.get(SessionLease, session_id)
    return None if row is None else _holder(row)


class _PgLock:
    """A session-level PostgreSQL advisory lock on a connection of its own (released if the process dies)."""

    def __init__(self, db: Database, session_id: int) -> None:
        self.key = advisory_key(_lock_name(session_id))
        self.conn = db.engine.connect().execution_options(isolation_level="AUTOCOMMIT")

    def try_lock(self) -> bool:
        return bool(self.conn.execute(text("SELECT pg_try_advisory_lock(:k)"), {"k": self.key}).scalar())

    def close(self) -> None:
        try:
            self.conn.execute(text("SELECT pg_advisory_unlock(:k)"), {"k": self.key})
        except Exception:  # the connection may already be gone; closing it releases the lock anyway
            pass
        self.conn.close()


def owner_alive(db: Database, holder: LeaseHolder) -> bool | None:
    """True: the holder provably runs; False: provably gone; None: cannot tell (another host, old heartbeat).

    On PostgreSQL the advisory lock answers exactly (a probe takes and drops it). On SQLite a holder on
    this host is alive while its pid is (a pid reused after a reboot shows as a stale heartbeat); on
    another host only the heartbeat speaks for it.
    """
    fresh = (utcnow() - holder.heartbeat_at) < timedelta(seconds=STALE_S)
    if db.dialect == "postgresql":
        probe = _PgLock(db, holder.session_id)
        try:
            free = probe.try_lock()
        finally:
            probe.close() if free else probe.conn.close()
        return not free
    if holder.host == socket.gethostname():
        if not _pid_alive(holder.pid):
            return False
        return True if fresh else None
    return True if fresh else None


class SessionLeaseHandle:
    """A held lease: keeps the heartbeat going (and the PostgreSQL lock held) until :meth:`release`."""

    def __init__(self, db: Database, session_id: int, token: str, pg_lock: _PgLock | None) -> None:
        self.db = db
        self.session_id = session_id
        self.token = token
        self._pg = pg_lock
        self._stop = threading.Event()
        self.lost = False
        self._thread: threading.Thread | None = None

    def start_heartbeat(self, interval_s: float = HEARTBEAT_S) -> None:
        # An in-memory SQLite database lives in this process alone (no other writer can exist), and a
        # heartbeat thread would get a connection of its own - another, empty database - so none is started
        # (simulated studies of a power analysis run in such databases, on Dask worker threads too).
        if is_sqlite(self.db.url) and sqlite_path(self.db.url) is None:
            return
        if self._thread is None:
            self._thread = threading.Thread(target=self._beat, args=(interval_s,), name="studyctl-lease",
                                            daemon=True)
            self._thread.start()

    def _beat(self, interval_s: float) -> None:
        while not self._stop.wait(interval_s):
            try:
                with self.db.in_transaction(durable=False) as tx:
                    n = tx.execute(update(SessionLease).where(SessionLease.session_id == self.session_id,
                                                              SessionLease.token == self.token)
                                   .values(heartbeat_at=utcnow())).rowcount
                if n == 0:
                    self.lost = True
                    return
            except Exception:  # a busy database: the next beat tries again
                continue

    def verify(self, tx: OrmSession) -> None:
        """Raise :class:`SessionError` unless this process still holds the lease (checked in ``tx``)."""
        token = tx.connection().scalar(_LEASE_TOKEN, {"session_id": self.session_id})
        if self.lost or token != self.token:
            self.lost = True
            raise SessionError(f"session {self.session_id} was taken over by another process (studyctl resume "
                               "--take-over); this process stops writing it")

    def release(self) -> None:
        """Stop the heartbeat and delete the lease row (only if it is still ours)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        try:
            with self.db.in_transaction() as tx:
                tx.execute(delete(SessionLease).where(SessionLease.session_id == self.session_id,
                                                      SessionLease.token == self.token))
        finally:
            if self._pg is not None:
                self._pg.close()
                self._pg = None


def take_lease(db: Database, tx: OrmSession, session_id: int, *, take_over: bool = False) -> SessionLeaseHandle:
    """Take the lease of ``session_id`` inside the caller's write transaction ``tx``.

    Refuses with the holder's pid, host and start time while another process holds it. A lease left
    behind is taken over (audited) only with ``take_over``: when its process is provably gone, or when its
    owner cannot be checked (another host) and its heartbeat is older than :data:`STALE_S`. The caller must call
    :meth:`SessionLeaseHandle.release` when the session stops (``start_heartbeat`` once it runs).
    """
    pg_lock: _PgLock | None = None
    if db.dialect == "postgresql":
        # Concurrent acquirers queue on the session row; the advisory lock then says whether the owner lives.
        tx.execute(text("SELECT id FROM session WHERE id = :i FOR UPDATE"), {"i": session_id})
        pg_lock = _PgLock(db, session_id)
        try:
            if not pg_lock.try_lock():
                row = tx.get(SessionLease, session_id)
                holder = _holder(row) if row is not None else None
                if holder is None:
                    raise SessionError(f"session {session_id} is being started by another process; try again")
                raise holder.refusal(" and still holds its PostgreSQL lock (it is connected)")
        except BaseException:
            pg_lock.conn.close()
            raise
    try:
        row = tx.get(SessionLease, session_id)
        if row is not None:
            holder = _holder(row)
            alive = False if pg_lock is not None else owner_alive(db, holder)
            if alive is True:
                raise holder.refusal()
            silent = (utcnow() - holder.heartbeat_at).total_seconds()
            if not take_over:  # a lease left behind is taken over only when the coordinator says so
                if alive is None:
                    raise holder.refusal(f" (no heartbeat for {silent:.0f} s)")
                raise holder.left_behind("its PostgreSQL connection is closed" if pg_lock is not None else
                                         f"no process {holder.pid} runs on this machine; last heartbeat "
                                         f"{silent:.0f} s ago")
            append_audit(tx, "session.take_over", entity="session", entity_id=session_id, details={
                "previous": {"pid": holder.pid, "host": holder.host, "since": holder.since,
                             "heartbeat_at": holder.heartbeat_at},
                "reason": "--take-over: the owner process is gone" if alive is False else "--take-over (owner not "
                          "reachable, heartbeat stale)",
                "by": {"pid": os.getpid(), "host": socket.gethostname()},
            })
            tx.delete(row)
            tx.flush()
        token = secrets.token_hex(16)
        now = utcnow()
        tx.add(SessionLease(session_id=session_id, token=token, pid=os.getpid(), host=socket.gethostname(),
                            acquired_at=now, heartbeat_at=now))
        tx.flush()
    except BaseException:
        if pg_lock is not None:
            pg_lock.close()
        raise
    return SessionLeaseHandle(db, session_id, token, pg_lock)


def lease_info(tx: OrmSession, session_id: int) -> dict[str, Any] | None:
    holder = current_holder(tx, session_id)
    if holder is None:
        return None
    return {"pid": holder.pid, "host": holder.host, "since": holder.since, "heartbeat_at": holder.heartbeat_at}


__all__ = ["HEARTBEAT_S", "STALE_S", "LeaseHolder", "SessionLeaseHandle", "current_holder", "lease_info",
           "owner_alive", "take_lease"]
