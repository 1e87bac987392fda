"""The results file of a power run (``power_results.sqlite`` in the output folder): finished replicates.

Each finished replicate is committed in one transaction (its tests' rows and its record together), so
an interrupted run loses at most the replicates that were still running, and the same command run again
skips what is there. The file remembers what its replicates depend on (protocol and plan digests,
population, master seed, studyctl version); a run with other settings refuses to add to it.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any

import pandas as pd

from studyctl.closing import Closeable
from studyctl.errors import StoreError, UsageError
from studyctl.power.replicate import ROW_COLUMNS, ReplicateResult

RESULTS_FILE = "power_results.sqlite"
REPLICATE_COLUMNS = (
    "participants",
    "replicate",
    "sessions_completed",
    "trials_completed",
    "trials_not_completed",
    "clipped",
    "seconds",
    "peak_rss_mb",
    "worker",
)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS replicates (
    participants INTEGER NOT NULL, replicate INTEGER NOT NULL, sessions_completed INTEGER NOT NULL,
    trials_completed INTEGER NOT NULL, trials_not_completed INTEGER NOT NULL, clipped INTEGER NOT NULL,
    seconds REAL NOT NULL, cpu_seconds REAL NOT NULL, peak_rss_mb REAL, worker TEXT NOT NULL,
    PRIMARY KEY (participants, replicate));
CREATE TABLE IF NOT EXISTS rows (
    participants INTEGER NOT NULL, replicate INTEGER NOT NULL, test_id TEXT NOT NULL, role TEXT, kind TEXT NOT NULL,
    test TEXT, metric TEXT, split TEXT, groups TEXT, parent TEXT, p REAL, p_adj REAL, significant INTEGER,
    effect_size_name TEXT, effect_size REAL, status TEXT,
    FOREIGN KEY (participants, replicate) REFERENCES replicates (participants, replicate));
CREATE INDEX IF NOT EXISTS rows_by_replicate ON rows (participants, replicate);
"""


class ResultsFile(Closeable):
    """Finished replicates of one power setup, kept in a SQLite file (open with :meth:`open`)."""

    def __init__(self, path: Path, conn: sqlite3.Connection) -> None:
        self.path = path
        self._conn = conn

    @classmethod
    def open(cls, folder: str | Path, fingerprint: dict[str, Any]) -> ResultsFile:
        """Open (or create) the results file in ``folder`` for runs with ``fingerprint``.

        Raises
        ------
        UsageError
            The folder holds results of another setup (names what differs and how to proceed).
        StoreError
            The folder or file cannot be created, or the file is not a results file.
        """
        root = Path(folder).expanduser()
        if root.exists() and not root.is_dir():
            raise UsageError(f"--out {root} is a file; give a folder for the power report")
        try:
            root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"cannot create the output folder {root}: {exc.strerror}; choose a writable one") from None
        path = root / RESULTS_FILE
        try:
            conn = sqlite3.connect(path, isolation_level=None, timeout=30)
            conn.execute("PRAGMA journal_mode = WAL")
            conn.execute("PRAGMA synchronous = NORMAL")
            conn.executescript(_SCHEMA)
            stored = conn.execute("SELECT value FROM meta WHERE key = 'fingerprint'").fetchone()
        except sqlite3.DatabaseError as exc:
            raise StoreError(
                f"{path} is not a readable power results file ({exc}); move it away or use another --out folder"
            ) from None
        wanted = json.dumps(fingerprint, sort_keys=True)
        if stored is None:
            conn.execute("INSERT INTO meta (key, value) VALUES ('fingerprint', ?)", (wanted,))
        elif stored[0] != wanted:
            conn.close()
            old = json.loads(stored[0])
            diff = [k for k in sorted(set(old) | set(fingerprint)) if old.get(k) != fingerprint.get(k)]
            raise UsageError(
                f"{path} holds replicates of another setup (different {', '.join(diff)}); "
                "use another --out folder, or delete that file to start over"
            )
        return cls(path, conn)

    @staticmethod
    def finished(folder: str | Path, fingerprint: dict[str, Any]) -> set[tuple[int, int]]:
        """The replicates already in ``folder``'s results file (empty when there is none), without creating
        anything; UsageError when the file holds another setup's replicates (as :meth:`open`)."""
        if not (Path(folder).expanduser() / RESULTS_FILE).is_file():
            return set()
        with ResultsFile.open(folder, fingerprint) as results:
            return results.done()

    def close(self) -> None:
        self._conn.close()

    def done(self) -> set[tuple[int, int]]:
        """(sample size, replicate) pairs already finished."""
        return {(int(n), int(r)) for n, r in self._conn.execute("SELECT participants, replicate FROM replicates")}

    def add(self, result: ReplicateResult) -> None:
        """Keep one finished replicate (atomically; a second copy of the same replicate is ignored)."""
        conn = self._conn
        conn.execute("BEGIN IMMEDIATE")
        try:
            cur = conn.execute(
                "INSERT OR IGNORE INTO replicates VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    result.participants,
                    result.replicate,
                    result.sessions_completed,
                    result.trials_completed,
                    result.trials_not_completed,
                    result.clipped,
                    result.seconds,
                    result.cpu_seconds,
                    result.peak_rss_mb,
                    result.worker,
                ),
            )
            if cur.rowcount:
                conn.executemany(
                    f"INSERT INTO rows VALUES ({', '.join('?' * len(ROW_COLUMNS))})",
                    [(result.participants, result.replicate, *_sql_row(row)) for row in result.rows],
                )
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            raise

    def rows(self, tasks: list[tuple[int, int]] | None = None) -> pd.DataFrame:
        """The tests' rows (``ROW_COLUMNS``), only of ``tasks`` when given."""
        frame = pd.read_sql_query("SELECT * FROM rows ORDER BY participants, replicate, rowid", self._conn)
        frame["significant"] = frame["significant"].map(lambda v: None if pd.isna(v) else bool(v)).astype(object)
        return _only(frame, tasks)[list(ROW_COLUMNS)]

    def replicates(self, tasks: list[tuple[int, int]] | None = None) -> pd.DataFrame:
        """One row per finished replicate (``REPLICATE_COLUMNS``), only of ``tasks`` when given."""
        frame = pd.read_sql_query("SELECT * FROM replicates ORDER BY participants, replicate", self._conn)
        return _only(frame, tasks)[list(REPLICATE_COLUMNS)]


def _sql_row(row: tuple[Any, ...]) -> tuple[Any, ...]:
    out = []
    for v in row:
        if isinstance(v, bool):
            v = int(v)
        elif isinstance(v, float) and v != v:
            v = None
        out.append(v)
    return tuple(out)


def _only(frame: pd.DataFrame, tasks: list[tuple[int, int]] | None) -> pd.DataFrame:
    if tasks is None or frame.empty:
        return frame.reset_index(drop=True)
    keys = pd.MultiIndex.from_frame(frame[["participants", "replicate"]])
    keep = keys.isin(pd.MultiIndex.from_tuples(tasks, names=["participants", "replicate"]))
    return frame[keep].reset_index(drop=True)
