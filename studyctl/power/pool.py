"""Stage 1 of the two-stage power design: a stored pool of virtual participants simulated through the full engine.

The pool is built in chunks; each chunk is one simulated study (:func:`studyctl.power.replicate.simulate_study`)
of ``chunk_size`` people — a whole number of counterbalancing blocks, so every order is used equally — each with
fresh traits drawn from the population, seeded by ``SeedSequence(seed, spawn_key=(pool, chunk_size, chunk))``.
What is kept per person is what the analysis plan reads: the metric rows the plan computed from the store, with
the person's stratum and counterbalancing sequence. Chunks are independent tasks (serial or on Dask, like
replicates) and committed one by one, so a pool grows and resumes; the file is keyed by everything its people
depend on (studyctl version, protocol, plan, population file sha256 and knobs, seed, loop rate, chunk size), so
another power run with the same settings reuses it.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import socket
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from studyctl.analysis.table import COLUMNS as METRIC_COLUMNS
from studyctl.errors import StoreError, UsageError
from studyctl.power.replicate import simulate_study
from studyctl.power.seeds import pool_seeds
from studyctl.power.spec import PowerSpec
from studyctl.power.target import block_period

#: The pool must hold at least this many people per participant of the largest sample size (issue 22): fewer,
#: and stage-2 replicates share so many people that their power is too optimistic about its own precision.
MIN_POOL_FACTOR = 20
#: A chunk holds at least this many people (tasks coarse enough that Dask's overhead stays small).
MIN_CHUNK = 10

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS chunks (chunk INTEGER PRIMARY KEY, seconds REAL NOT NULL, cpu_seconds REAL NOT NULL,
    worker TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS members (member TEXT PRIMARY KEY, chunk INTEGER NOT NULL, stratum TEXT NOT NULL,
    sequence INTEGER);
CREATE TABLE IF NOT EXISTS metrics (member TEXT NOT NULL, "group" TEXT, condition TEXT, trial TEXT,
    repetition TEXT, metric TEXT, level TEXT, value REAL, denominator REAL);
CREATE INDEX IF NOT EXISTS metrics_by_member ON metrics (member);
"""


def chunk_size(protocol: Any) -> int:
    """People per pool chunk: the smallest whole number of counterbalancing blocks with at least MIN_CHUNK."""
    from studyctl.power.target import completes_blocks

    step = max(block_period(protocol)[0], 1)
    n = step
    while n < MIN_CHUNK or not completes_blocks(protocol, n):
        n += step
    return n


#: Parts of the package that do not shape a simulated person's metric rows (a change there keeps a pool valid):
#: the statistics and stage 2's own modules run on the stored rows every time, they never made them.
_NOT_SIMULATION = ("bench", "cli", "report", "view", "workflows", "stats")
_NOT_SIMULATION_FILES = tuple(f"power/{m}.py" for m in ("twostage", "units", "summary", "target", "results",
                                                         "executor", "bootstrap", "fast", "arrays")) + \
    tuple(f"analysis/{m}.py" for m in ("execute", "shape", "results", "run", "effect_ci", "model_ci",
                                       "result_tables", "figure_data"))
#: Folders of the package that only test stored rows (the plan's procedures; a pool keeps no test result).
_NOT_SIMULATION_DIRS = ("analysis/procedures",)
#: Shipped population and targets files: the pool's own population is in its key already (the spec's
#: ``traits_sha256``); another protocol's population or a targets file never shapes its people, and hashing them
#: made a fit of seed 003's population invalidate every stored seed-000 pool (issue 22, measured: a 460 s rebuild).
_NOT_SIMULATION_DATA = ("populations",)


def simulation_code_digest() -> str:
    """sha256 of the package's source files that simulate and measure people (engine, participants, scenes,
    controllers, devices, models, protocol, the analysis's metrics, populations …); the analysis modules that
    prepare and test stored metric rows (execute, shape, procedures …) run on a pool's rows, never made them.
    The version number alone does not change while the code does: a pool grown in chunks across a code change
    would mix two kinds of virtual people (seen while measuring issue 22: chunks built before and after a
    devices/engine change landed)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for rel in simulation_files():
        h.update(str(rel).encode())
        h.update(hashlib.sha256((root / rel).read_bytes()).digest())
    return h.hexdigest()


def simulation_files() -> list[Path]:
    """The package's files :func:`simulation_code_digest` reads (relative to the package), sorted."""
    root = Path(__file__).resolve().parents[1]
    out = []
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root)
        if not path.is_file() or path.suffix not in (".py", ".yaml", ".yml", ".json", ".npz") or \
                rel.parts[0] in _NOT_SIMULATION or rel.as_posix() in _NOT_SIMULATION_FILES or \
                rel.parent.as_posix() in _NOT_SIMULATION_DIRS or "__pycache__" in rel.parts or \
                (rel.parent.as_posix() in _NOT_SIMULATION_DATA and path.suffix != ".py"):
            continue
        out.append(rel)
    return out


def pool_key(spec: PowerSpec, size: int) -> dict[str, Any]:
    """What the pool's people depend on (not the sample sizes or replicates of a run), the simulation code too."""
    fp = spec.fingerprint()
    return {**fp, "chunk_size": size, "code_sha256": simulation_code_digest(), "kind": "studyctl-power-pool/1"}


def check_pool_size(pool: int | None, sizes: tuple[int, ...]) -> int:
    """The pool size to use: ``pool`` (default MIN_POOL_FACTOR × the largest n), refused when too small."""
    need = MIN_POOL_FACTOR * max(sizes)
    if pool is None:
        return need
    if isinstance(pool, bool) or not isinstance(pool, int) or pool < need:
        raise UsageError(
            f"--pool {pool!r}: the pool must hold at least {MIN_POOL_FACTOR} × the largest sample size "
            f"({MIN_POOL_FACTOR} × {max(sizes)} = {need}) virtual participants; use --pool {need} or more "
            f"(or leave --pool out), or a smaller largest --participants"
        )
    return pool


@dataclass(frozen=True)
class PoolChunk:
    """One simulated chunk: its people (member id, stratum, sequence) and their metric rows."""

    chunk: int
    members: tuple[tuple[str, str, int | None], ...]
    metrics: pd.DataFrame
    seconds: float
    cpu_seconds: float
    worker: str


def simulate_chunk(spec: PowerSpec, size: int, chunk: int) -> PoolChunk:
    """Simulate pool chunk ``chunk`` (``size`` people) through the full engine; a Dask task."""
    t0, c0 = time.perf_counter(), time.process_time()
    seeds = pool_seeds(spec.seed, size, chunk)
    out = simulate_study(spec, size, seeds, f"{spec.study_id}-pool-c{chunk}", f"pool chunk {chunk}")
    rename = {code: f"c{chunk:05d}-{code}" for code, _, _ in out.members}
    frame = out.table.frame.loc[:, list(METRIC_COLUMNS)].copy()
    frame["participant"] = frame["participant"].map(rename)
    members = tuple((rename[code], stratum, seq) for code, stratum, seq in out.members)
    return PoolChunk(chunk, members, frame.reset_index(drop=True), time.perf_counter() - t0,
                     time.process_time() - c0, f"{socket.gethostname()}:{os.getpid()}")


@dataclass(frozen=True)
class Pool:
    """A loaded pool: people (member, chunk, stratum, sequence) and their metric rows (participant = member)."""

    path: Path
    members: pd.DataFrame
    metrics: pd.DataFrame
    chunk_size: int
    build_seconds: float
    build_cpu_seconds: float
    built_now: int

    @property
    def size(self) -> int:
        return len(self.members)


class PoolFile:
    """The SQLite file of one pool (keyed by :func:`pool_key`)."""

    def __init__(self, path: Path, conn: sqlite3.Connection) -> None:
        self.path, self._conn = path, conn

    @classmethod
    def open(cls, folder: str | Path, key: dict[str, Any], protocol_name: str) -> PoolFile:
        digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()
        folder = Path(folder).expanduser()
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / f"{protocol_name}-{digest[:16]}.sqlite"
            conn = sqlite3.connect(path, isolation_level=None)
            conn.executescript(_SCHEMA)
            text = json.dumps(key, sort_keys=True, default=str)
            conn.execute("INSERT OR IGNORE INTO meta VALUES ('key', ?)", (text,))
        except (OSError, sqlite3.Error) as exc:
            raise StoreError(f"pool folder {folder}: cannot write the pool file ({exc}); give a writable "
                             "--pool-dir") from None
        return cls(path, conn)

    def close(self) -> None:
        self._conn.close()

    def chunks(self) -> set[int]:
        return {r[0] for r in self._conn.execute("SELECT chunk FROM chunks")}

    def add(self, part: PoolChunk) -> None:
        """Commit one chunk (its people and rows together)."""
        c = self._conn
        c.execute("BEGIN")
        try:
            c.executemany("INSERT INTO members VALUES (?, ?, ?, ?)",
                          [(m, part.chunk, s, None if q is None else int(q)) for m, s, q in part.members])
            rows = part.metrics.astype(object).where(part.metrics.notna(), None)
            c.executemany("INSERT INTO metrics VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                          [tuple(None if v is None else (str(v) if i < 7 else float(v)) for i, v in enumerate(r))
                           for r in rows[list(METRIC_COLUMNS)].itertuples(index=False, name=None)])
            c.execute("INSERT INTO chunks VALUES (?, ?, ?, ?)", (part.chunk, part.seconds, part.cpu_seconds,
                                                                 part.worker))
            c.execute("COMMIT")
        except BaseException:
            c.execute("ROLLBACK")
            raise

    def load(self, chunks: int, size: int, built_now: int) -> Pool:
        members = pd.read_sql_query(
            "SELECT member, chunk, stratum, sequence FROM members WHERE chunk < ? ORDER BY chunk, member",
            self._conn, params=(chunks,))
        metrics = pd.read_sql_query(
            'SELECT m.* FROM metrics m JOIN members p ON p.member = m.member WHERE p.chunk < ?', self._conn,
            params=(chunks,)).rename(columns={"member": "participant"})
        for col in ("trial", "repetition"):  # stored as text; the metric table holds numbers there
            metrics[col] = _numbers(metrics[col])
        t = self._conn.execute("SELECT COALESCE(SUM(seconds), 0), COALESCE(SUM(cpu_seconds), 0) FROM chunks "
                               "WHERE chunk < ?", (chunks,)).fetchone()
        return Pool(self.path, members, metrics[list(METRIC_COLUMNS)], size, float(t[0]), float(t[1]), built_now)


def _numbers(col: pd.Series) -> pd.Series:
    try:
        return pd.to_numeric(col)
    except (TypeError, ValueError):
        return col


def build_pool(spec: PowerSpec, folder: str | Path, people: int, backend: Any = None,
               on_chunk: Any = None) -> Pool:
    """Stage 1: make sure the pool in ``folder`` holds at least ``people`` people; simulate the missing chunks.

    ``backend`` (from :func:`studyctl.power.executor.open_backend`) runs the chunks; None: serially here.
    ``on_chunk(done, total)`` is called after each chunk.
    """
    protocol = spec.load_protocol()
    size = chunk_size(protocol)
    chunks = math.ceil(people / size)
    pf = PoolFile.open(folder, pool_key(spec, size), spec.protocol_name)
    try:
        todo = [c for c in range(chunks) if c not in pf.chunks()]
        done = [chunks - len(todo)]

        def keep(part: PoolChunk) -> None:
            pf.add(part)
            done[0] += 1
            if on_chunk is not None:
                on_chunk(done[0], chunks)

        if todo:
            if backend is None:
                for c in todo:
                    keep(simulate_chunk(spec, size, c))
            else:
                backend.map(simulate_chunk, spec, [(size, c) for c in todo], keep, tag="pool")
        return pf.load(chunks, size, len(todo))
    finally:
        pf.close()
