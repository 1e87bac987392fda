"""The audit chain's head anchored outside the database, so a deleted tail is seen.

``audit_head`` inside the database can be rewritten together with the rows it describes. After every
commit that appends audit rows, studyctl also writes the head (row count and last hash) to a small file
outside the database: next to a SQLite file (``study.db.head``), and for PostgreSQL in
``$STUDYCTL_AUDIT_HEAD_DIR`` (default ``~/.local/state/studyctl/audit-heads/``) under the server and
database name. ``studyctl run``/``resume`` also print the head for the lab notebook, and
``studyctl audit verify --head N:HASH`` checks the log against a noted head.

The file only moves forward (a writer never replaces a longer head with a shorter one), so a log that
is shorter than the file, or whose row N no longer has the noted hash, was truncated or rewritten.

Just before such a commit the file also records the head the commit will make (``pending``), and just after it
the committed head replaces both: a process killed between its commit and the head file's update leaves a
database one commit ahead of the file, at exactly the pending head, which is not a tampered tail.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from sqlalchemy import URL, event, select
from sqlalchemy.orm import Session as OrmSession

from studyctl.errors import UsageError
from studyctl.store.models import AuditLog

HEAD_KEY = "studyctl_audit_head"  # ORM session.info key: (count, hash) appended in this transaction
_FORMAT = "studyctl-audit-head/1"
_HEX64 = re.compile(r"^[0-9a-f]{64}$")


@dataclass(frozen=True)
class Head:
    count: int
    hash: str
    pending: Head | None = None  # in a head file: the head a commit under way will make (see the module doc)

    def text(self) -> str:
        return f"{self.count}:{self.hash}"


def parse_head(value: str) -> Head:
    """``N:HASH`` (as printed by run/resume and ``audit verify``) → :class:`Head`."""
    count, _, digest = value.strip().partition(":")
    if not count.isdigit() or not _HEX64.match(digest.lower()):
        raise UsageError(f"--head {value!r} is not ROWS:SHA256 (e.g. 42:3fa9…, 64 hex digits) as printed by "
                         "`studyctl run`, `resume` or `audit verify`")
    return Head(int(count), digest.lower())


def anchor_path(url: URL) -> Path | None:
    """Where the head file of the database at ``url`` lives (None for an in-memory database)."""
    if url.get_backend_name() == "sqlite":
        if url.database in (None, "", ":memory:"):
            return None
        return Path(f"{url.database}.head")
    folder = os.environ.get("STUDYCTL_AUDIT_HEAD_DIR")
    base = Path(folder) if folder else Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state") \
        / "studyctl" / "audit-heads"
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", f"{url.host or 'local'}_{url.port or 5432}_{url.database}")
    return base / f"{name}.head"


def read_anchor(path: Path) -> Head | None:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    parts = text.split()
    if len(parts) not in (3, 6) or parts[0] != _FORMAT or not _is_head(parts[1:3]):
        return None
    if len(parts) == 6:  # FORMAT COUNT HASH pending COUNT HASH
        if parts[3] != "pending" or not _is_head(parts[4:6]):
            return None
        return Head(int(parts[1]), parts[2], Head(int(parts[4]), parts[5]))
    return Head(int(parts[1]), parts[2])


def _is_head(parts: list[str]) -> bool:
    return parts[0].isdigit() and bool(_HEX64.match(parts[1]))


def write_anchor(path: Path, head: Head, *, pending: bool = False) -> None:
    """Record ``head`` in the file unless it already holds a longer one; with ``pending``, record it as the head a
    commit under way will make, beside the file's committed head. Never fails the caller's work: a head file that
    cannot be written only weakens the later check."""
    try:
        current = read_anchor(path)
        if current is not None and current.count >= head.count:
            return
        line = f"{_FORMAT} {head.count} {head.hash}"
        if pending:
            committed = current or Head(0, "0" * 64)
            line = f"{_FORMAT} {committed.count} {committed.hash} pending {head.count} {head.hash}"
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        fd = os.open(tmp, os.O_CREAT | os.O_TRUNC | os.O_WRONLY, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(line + "\n")
        os.replace(tmp, path)
    except OSError:
        pass


def _span(first: int, last: int) -> str:
    return str(first) if first == last else f"{first}–{last}"


def check_head(tx: OrmSession, head: Head, source: str, *, strict_tail: bool) -> tuple[list[str], list[str]]:
    """Problems and notes from comparing the stored log with a head recorded outside it.

    ``strict_tail``: rows after the recorded head are a problem (a SQLite file, written only on this
    machine, always advances its head file) rather than a note (PostgreSQL, where other machines write).
    """
    problems: list[str] = []
    notes: list[str] = []
    rows = tx.scalar(select(AuditLog.id).order_by(AuditLog.id.desc()).limit(1)) or 0
    if head.count > rows:
        problems.append(f"tail truncated: {source} records {head.count} audit rows ending in {head.hash[:16]}…, the "
                        f"database holds {rows}: audit row(s) {_span(rows + 1, head.count)} were deleted")
        return problems, notes
    if head.count:
        stored = tx.scalar(select(AuditLog.hash).where(AuditLog.id == head.count))
        if stored != head.hash:
            problems.append(f"audit row {head.count} does not have the hash {source} records ({head.hash[:16]}…): "
                            "the log was rewritten from that row or earlier")
    if rows > head.count:
        msg = f"audit row(s) {_span(head.count + 1, rows)} are not in {source}"
        pending = head.pending
        if pending is not None and pending.count == rows and tx.scalar(
                select(AuditLog.hash).where(AuditLog.id == rows)) == pending.hash:
            # the commit that wrote them had announced them: studyctl stopped between its commit and the file's update
            notes.append(f"{msg} but are the commit it recorded as under way (studyctl stopped before updating it)")
        elif strict_tail:
            problems.append(f"{msg}: they were inserted outside studyctl (or studyctl stopped right after writing "
                            "them)")
        else:
            notes.append(f"{msg} (written elsewhere, e.g. another site)")
    return problems, notes


def audit_head(db) -> Head:
    """The database's current audit head (row count and last hash), e.g. to print for the lab notebook."""
    from studyctl.store.models import AuditHead

    with db.reading() as tx:
        row = tx.get(AuditHead, 1)
        return Head(int(row.count), str(row.hash)) if row is not None else Head(0, "0" * 64)


def _anchor_of(session: OrmSession) -> Path | None:
    try:
        url = session.get_bind().engine.url
    except Exception:  # unbound session: nothing to anchor
        return None
    return anchor_path(url)


def _before_commit(session: OrmSession) -> None:
    head = session.info.get(HEAD_KEY)
    if head is not None and (path := _anchor_of(session)) is not None:
        write_anchor(path, Head(*head), pending=True)


def _after_commit(session: OrmSession) -> None:
    head = session.info.pop(HEAD_KEY, None)
    if head is not None and (path := _anchor_of(session)) is not None:
        write_anchor(path, Head(*head))


def _after_rollback(session: OrmSession) -> None:
    session.info.pop(HEAD_KEY, None)


# Every ORM commit that appended audit rows (append_audit notes the new head in session.info) advances
# the head file, whichever code path opened the transaction.
event.listen(OrmSession, "before_commit", _before_commit)
event.listen(OrmSession, "after_commit", _after_commit)
event.listen(OrmSession, "after_soft_rollback", lambda session, _tx: _after_rollback(session))


__all__ = ["HEAD_KEY", "Head", "anchor_path", "audit_head", "check_head", "parse_head", "read_anchor", "write_anchor"]
