"""The append-only, hash-chained audit log.

Row ``k`` stores ``hash_k = sha256(hash_{k-1} + canonical_json(row_k))`` with ``hash_0`` the genesis
value (64 zeros); ids run 1, 2, 3 … without gaps, and the single ``audit_head`` row keeps the count and
the last hash. :func:`verify_audit` therefore detects an edited row (its hash no longer matches), a
rewritten hash (the next row's ``prev_hash`` no longer matches), a row deleted in the middle (a gap in
the ids) and a deleted tail (the head disagrees). Publishing the head hash (``studyctl audit verify``
prints it) also pins the log against someone who rewrites the whole chain.
"""

from __future__ import annotations

import getpass
import hashlib
import json
import os
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import bindparam, select, update
from sqlalchemy.orm import Session
from sqlalchemy.orm.util import identity_key

from studyctl.errors import UsageError, ValueTypeError
from studyctl.store.anchor import HEAD_KEY
from studyctl.store.models import AuditHead, AuditLog

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)

GENESIS_HASH = "0" * 64
_HASHED_FIELDS = ("id", "at", "actor", "action", "entity", "entity_id", "details")


def canonical_json(value: Any) -> str:
    """JSON with sorted keys, no spaces, UTF-8 kept, NaN refused: the same text for the same value."""
    try:
        return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False,
                          default=_json_default)
    except ValueError as exc:
        raise UsageError(f"audit details must be finite JSON values: {exc}") from None


def _json_default(value: Any) -> Any:
    if isinstance(value, datetime):
        return value.astimezone(UTC).isoformat()
    if hasattr(value, "item"):  # numpy scalars
        return value.item()
    raise ValueTypeError(f"cannot store {type(value).__name__} {value!r} in the audit log; pass JSON values")


def row_hash(prev_hash: str, row: dict[str, Any]) -> str:
    """``sha256(prev_hash + canonical JSON of the row's hashed fields)`` as hex."""
    body = canonical_json({k: row[k] for k in _HASHED_FIELDS})
    return hashlib.sha256((prev_hash + body).encode("utf-8")).hexdigest()


def default_actor() -> str:
    """Who acts: ``STUDYCTL_ACTOR`` if set, else the operating-system user."""
    actor = os.environ.get("STUDYCTL_ACTOR")
    if actor:
        return actor
    try:
        return getpass.getuser()
    except Exception:  # no passwd entry (some containers)
        return f"uid:{os.getuid()}"


# Every write transaction of a session appends a seal row (hundreds per session), so the head's read and update
# are built once and run on the transaction's connection (Core): the same SQL (the read FOR UPDATE, so concurrent
# PostgreSQL writers queue) without ORM statement construction and identity-map handling per row.
_HEAD = select(AuditHead.count, AuditHead.hash).where(AuditHead.id == 1).with_for_update()
_ADVANCE_HEAD = (update(AuditHead).where(AuditHead.id == 1)
                 .values(count=bindparam("new_count"), hash=bindparam("new_hash")))


def append_audit(
    session: Session,
    action: str,
    *,
    entity: str | None = None,
    entity_id: Any = None,
    details: dict[str, Any] | None = None,
    actor: str | None = None,
) -> AuditLog:
    """Append one audit row inside the caller's write transaction and advance the chain head.

    The head row is read ``FOR UPDATE`` so concurrent PostgreSQL writers queue; on SQLite the
    caller's ``BEGIN IMMEDIATE`` transaction already serialises them.
    """
    if not action:
        raise UsageError("audit action must be a non-empty string")
    session.flush()  # rows the caller added go first, as the ORM query's autoflush did
    conn = session.connection()
    head = conn.execute(_HEAD).one_or_none()
    if head is None:
        session.add(AuditHead(id=1, count=0, hash=GENESIS_HASH))
        session.flush()
        count, prev_hash = 0, GENESIS_HASH
    else:
        count, prev_hash = head
    row = {
        "id": count + 1,
        "at": datetime.now(UTC).isoformat(timespec="microseconds"),
        "actor": actor or default_actor(),
        "action": action,
        "entity": entity,
        "entity_id": None if entity_id is None else str(entity_id),
        "details": canonical_json(details or {}),
    }
    digest = row_hash(prev_hash, row)
    entry = AuditLog(**row, prev_hash=prev_hash, hash=digest)
    session.add(entry)
    session.flush()
    conn.execute(_ADVANCE_HEAD, {"new_count": row["id"], "new_hash": digest})
    held = session.identity_map.get(identity_key(AuditHead, 1))
    if held is not None:  # a head row loaded earlier in this transaction reads the new head next time
        session.expire(held)
    session.info[HEAD_KEY] = (row["id"], digest)  # the head file follows once this commits (store.anchor)
    return entry


@dataclass(frozen=True)
class AuditReport:
    """Result of :func:`verify_audit`: ``ok`` when every check passed, else ``problems`` (one per line)."""

    rows: int
    head_hash: str
    problems: tuple[str, ...] = field(default_factory=tuple)
    bad_ids: tuple[int, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return not self.problems

    def to_frame(self) -> pd.DataFrame:
        """One row per problem: columns ``row_id`` (None for whole-log problems) and ``problem``."""
        import pandas as pd

        ids: list[int | None] = list(self.bad_ids) + [None] * (len(self.problems) - len(self.bad_ids))
        return pd.DataFrame({"row_id": pd.Series(ids, dtype="Int64"), "problem": list(self.problems)},
                            columns=["row_id", "problem"])


def _span(first: int, last: int) -> str:
    return str(first) if first == last else f"{first}–{last}"


def verify_audit(session: Session, *, batch: int = 2000) -> AuditReport:
    """Walk the chain from the genesis hash and report every edited, deleted or re-hashed row."""
    problems: list[str] = []
    bad: list[int] = []
    expected_id = 1
    prev = GENESIS_HASH
    rows = 0
    stmt = select(AuditLog).order_by(AuditLog.id).execution_options(yield_per=batch)
    for entry in session.scalars(stmt):
        rows += 1
        if entry.id != expected_id:
            missing = f"{expected_id}" if entry.id == expected_id + 1 else f"{expected_id}–{entry.id - 1}"
            problems.append(f"audit row(s) {missing} deleted: ids jump from {expected_id - 1} to {entry.id}")
            bad.append(expected_id)
        fields = {k: getattr(entry, k) for k in _HASHED_FIELDS}
        if entry.prev_hash != prev:
            problems.append(f"audit row {entry.id} ({entry.action}): prev_hash does not match the hash of the row "
                            "before it: that row was rewritten or removed")
            bad.append(entry.id)
        if row_hash(entry.prev_hash, fields) != entry.hash:
            problems.append(f"audit row {entry.id} ({entry.action}) was edited: its content no longer matches "
                            "its hash")
            bad.append(entry.id)
        prev = entry.hash
        expected_id = entry.id + 1
    head = session.get(AuditHead, 1)
    if head is None:
        if rows:
            problems.append("the audit head row is missing")
    else:
        last = expected_id - 1
        if head.count > last:
            problems.append(f"the audit log ends at row {last} but its head records {head.count} rows: "
                            f"audit row(s) {_span(last + 1, head.count)} at the end were deleted (or the head was "
                            "edited)")
        elif head.count < last:
            problems.append(f"audit row(s) {_span(head.count + 1, last)} come after the head ({head.count} rows): "
                            "they were inserted (or the head was edited)")
            bad.append(head.count + 1)
        elif head.hash != prev:
            problems.append(f"the audit head's hash does not match row {last}: the head or the last row was edited")
    # Keep bad_ids aligned with the row-level problems only.
    return AuditReport(rows=rows, head_hash=prev, problems=tuple(problems), bad_ids=tuple(bad))


__all__ = ["GENESIS_HASH", "AuditReport", "append_audit", "canonical_json", "default_actor", "row_hash",
           "verify_audit"]
