"""Database maintenance behind ``studyctl db``: upgrade the schema, check integrity."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from sqlalchemy import func, select

from studyctl.errors import IntegrityError
from studyctl.store.db import Database, SchemaState, require_head
from studyctl.store.integrity import verify_session
from studyctl.store.models import SampleChunk

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)


def upgrade_database(url: Any) -> tuple[str | None, SchemaState]:
    """Migrate ``url`` to head; returns the revision before and the state after."""
    with Database.open(url, check_schema=False) as db:
        before = db.schema_state().current
        after = db.upgrade()
    return before, after


@dataclass(frozen=True)
class DatabaseCheck:
    """Result of :func:`check_database`: each check's name, whether it passed, and what it found."""

    database: str
    checks: tuple[tuple[str, bool, str], ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return all(passed for _, passed, _ in self.checks)

    def to_frame(self) -> pd.DataFrame:
        import pandas as pd

        return pd.DataFrame(list(self.checks), columns=["check", "passed", "detail"])

    def lines(self) -> list[str]:
        return [f"{'ok  ' if passed else 'FAIL'} {name}: {detail}" for name, passed, detail in self.checks]

    def raise_for_problems(self) -> None:
        if not self.ok:
            failed = ", ".join(name for name, passed, _ in self.checks if not passed)
            raise IntegrityError(f"{self.database} fails: {failed}; restore it from a backup")


def check_database(url: Any) -> DatabaseCheck:
    """Run SQLite's integrity and foreign-key checks, verify the audit chain and the sample chunks' sizes."""
    checks: list[tuple[str, bool, str]] = []
    with Database.open(url, check_schema=False) as db:
        state = db.schema_state()
        require_head(state, db.describe())
        checks.append(("schema", True, f"revision {state.current}"))
        if db.dialect == "sqlite":
            with db.engine.connect() as conn:
                result = [r[0] for r in conn.exec_driver_sql("PRAGMA integrity_check").fetchall()]
                fk = conn.exec_driver_sql("PRAGMA foreign_key_check").fetchall()
            checks.append(("sqlite integrity", result == ["ok"], "; ".join(result[:5])))
            checks.append(("foreign keys", not fk, f"{len(fk)} dangling reference(s)" if fk else "ok"))
        with db.reading() as s:
            full = verify_session(s, db)
            report = full.audit
            checks.append(("audit chain", report.ok,
                           f"{report.rows} rows, head {report.head_hash}" if report.ok else "; ".join(report.problems)))
            checks.append(("audit head file", not full.head_problems,
                           "; ".join(full.head_problems) or "; ".join(n for n in full.notes if "head" in n) or "ok"))
            rec_problems = [p.line() for p in full.records.problems if p.kind != "chunk"]
            checks.append(("sealed records", not rec_problems,
                           "; ".join(rec_problems) if rec_problems else
                           full.records.summary(("trial", "event", "answer", "report"))))
            chunk_problems = [p.line() for p in full.records.problems if p.kind == "chunk"]
            checks.append(("sample digests", not chunk_problems,
                           "; ".join(chunk_problems) if chunk_problems else
                           f"{full.records.checked['chunk']} chunks match their sealed digests"))
            bad = []
            rows = s.execute(select(SampleChunk.id, SampleChunk.n, SampleChunk.channels, SampleChunk.dtype,
                                    func.length(SampleChunk.t), func.length(SampleChunk.data))).all()
            for cid, n, channels, dtype, t_len, d_len in rows:
                if t_len != 8 * n or d_len != n * len(channels) * np.dtype(dtype).itemsize:
                    bad.append(cid)
            checks.append(("sample chunks", not bad,
                           f"{len(rows)} chunks" if not bad else f"chunk ids {bad[:10]} have wrong sizes"))
        return DatabaseCheck(database=db.describe(), checks=tuple(checks))


__all__ = ["DatabaseCheck", "check_database", "upgrade_database"]
