"""One check of everything stored: the audit chain, every sealed record, and the head kept outside.

Behind ``studyctl audit verify`` and ``studyctl db check``: names each edited, deleted or inserted audit row
or record, and a truncated tail (against the head file next to the database, or a head noted in the lab
notebook and passed as ``--head``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from sqlalchemy.orm import Session as OrmSession

from studyctl.store.anchor import Head, anchor_path, check_head, read_anchor
from studyctl.store.audit import AuditReport, verify_audit
from studyctl.store.db import Database
from studyctl.store.records import RecordsReport, verify_records

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)


@dataclass(frozen=True)
class IntegrityReport:
    """Audit chain + records + outside head. ``problems`` are tampering (or damage); ``notes`` are not."""

    audit: AuditReport
    records: RecordsReport
    head_problems: tuple[str, ...]
    notes: tuple[str, ...]

    @property
    def problems(self) -> tuple[str, ...]:
        return (*self.audit.problems, *(p.line() for p in self.records.problems), *self.head_problems)

    @property
    def ok(self) -> bool:
        return not self.problems

    def to_frame(self) -> pd.DataFrame:
        """One row per problem: ``what`` (audit, trial, event, answer, report, chunk, head), ``id``, ``problem``."""
        import pandas as pd

        rows: list[tuple[str, int | None, str]] = []
        ids = list(self.audit.bad_ids) + [None] * (len(self.audit.problems) - len(self.audit.bad_ids))
        rows += [("audit", i, p) for i, p in zip(ids, self.audit.problems, strict=True)]
        rows += [(p.kind, p.record_id, p.line()) for p in self.records.problems]
        rows += [("head", None, p) for p in self.head_problems]
        frame = pd.DataFrame(rows, columns=["what", "id", "problem"])
        frame["id"] = frame["id"].astype("Int64")
        return frame


def verify_session(tx: OrmSession, db: Database, head: Head | None = None, *, single_site: bool = False
                   ) -> IntegrityReport:
    """``single_site``: on PostgreSQL, every machine that writes the database anchors its head in the same head
    file (one machine, or ``STUDYCTL_AUDIT_HEAD_DIR`` on a folder they all share), so audit rows after that head
    are a problem, as on SQLite, instead of a note (rows another site may have written)."""
    audit = verify_audit(tx)
    records = verify_records(tx)
    head_problems: list[str] = []
    notes: list[str] = list(records.notes)
    path = anchor_path(db.url)
    strict = db.dialect == "sqlite" or single_site
    anchored = read_anchor(path) if path is not None else None
    if anchored is not None:
        p, n = check_head(tx, anchored, f"the head file {path}", strict_tail=strict)
        head_problems += p
        notes += n
    elif path is not None:
        notes.append(f"no head file at {path}: the end of the log is checked against the database's own head only")
    if head is not None:
        p, n = check_head(tx, head, f"the head you gave ({head.count}:{head.hash[:16]}…)", strict_tail=False)
        head_problems += p
        notes += n
    return IntegrityReport(audit=audit, records=records, head_problems=tuple(head_problems), notes=tuple(notes))


def verify_integrity(db: Database, head: Head | None = None, *, single_site: bool = False) -> IntegrityReport:
    """Check the audit chain, every sealed record and the outside head of ``db`` in one read snapshot
    (``single_site``: see :func:`verify_session`)."""
    with db.reading() as tx:
        return verify_session(tx, db, head, single_site=single_site)


__all__ = ["IntegrityReport", "verify_integrity", "verify_session"]
