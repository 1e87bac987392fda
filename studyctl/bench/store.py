"""``studyctl bench store``: durable high-rate sample writes, trial reads and bytes per value.

A trial here is 90 s × 1 kHz × 16 channels of float64 (1.44 M values), written through
:class:`~studyctl.store.samples.SampleWriter` with its default 1 s flush interval: every flush is one
committed transaction (90 per trial), i.e. the durability the store promises, not a bulk load.
PostgreSQL runs with ``fsync=on``.

Figures (SQLite, then PostgreSQL with a ``pg_`` prefix):

- ``write_values_per_s``: values per wall second, samples arriving in 100-row blocks, ending with the
  trial's durable completion commit. Flushes use the default durability: each survives the process
  being killed; the completion commit fsyncs them all.
- ``write_values_per_s_rowwise``: the same, one ``append`` call per 16-channel row (a 1 kHz tick loop).
- ``write_values_per_s_fsync_each_flush``: ``durable_flush=True``, every 1 s chunk fsynced on its own.
- ``read_trial_ms``: median time to read one trial back into a pandas DataFrame.
- ``bytes_per_value``: growth of the database (SQLite file; PostgreSQL ``sample_chunk`` relation incl.
  TOAST) per stored value. Values are random normals, so nothing compresses.

Peer (same run, same durability): one row per value ``(trial_id, t, channel, value)`` in SQLite,
committed once per second of samples, read back and pivoted to the same wide DataFrame.

A PostgreSQL server is started for the run (initdb into a temp folder, loopback only) unless
``STUDYCTL_BENCH_PG`` names a database URL to use instead.
"""

from __future__ import annotations

import os
import sqlite3
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from studyctl.bench import BenchResult
from studyctl.errors import BenchmarkError
from studyctl.store.repository import StudyStore

RATE = 1000
CHANNELS = [f"ch{i:02d}" for i in range(16)]
BLOCK = 100


def _trial_data(seconds: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    n = int(seconds * RATE)
    rng = np.random.default_rng(seed)
    return np.arange(n) / RATE, rng.standard_normal((n, len(CHANNELS)))


def _new_trial(store: StudyStore, study_id: int, code: str) -> int:
    participant = store.add_participant(study_id, code)
    session = store.start_session(participant.id)
    return store.add_trial(session.id, plan_position=0, condition="bench").id


def _write_blocks(store: StudyStore, trial_id: int, t: np.ndarray, v: np.ndarray, durable_flush: bool = False) -> float:
    start = time.perf_counter()
    # seal=False as in the session engine: the chunks are sealed with the trial's completion below
    with store.sample_writer(trial_id, CHANNELS, durable_flush=durable_flush, seal=False) as writer:
        for i in range(0, len(t), BLOCK):
            writer.append_block(t[i : i + BLOCK], v[i : i + BLOCK])
    # The trial's completion is the durable (fsynced) commit that seals its chunks.
    store.update_trial(trial_id, status="completed")
    return time.perf_counter() - start


def _write_rows(store: StudyStore, trial_id: int, t: np.ndarray, v: np.ndarray) -> float:
    start = time.perf_counter()
    with store.sample_writer(trial_id, CHANNELS, seal=False) as writer:
        append = writer.append
        for i in range(len(t)):
            append(t[i], v[i])
    store.update_trial(trial_id, status="completed")
    return time.perf_counter() - start


def _median_ms(fn: Callable[[], object], repeat: int) -> float:
    fn()  # warm-up: page cache and connection pool
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def _measure(store: StudyStore, size: Callable[[], int], seconds: float, trials: int, reads: int,
             tag: str) -> dict[str, float]:
    study = store.create_study(f"bench-{tag}-{time.time_ns()}")
    values_per_trial = int(seconds * RATE) * len(CHANNELS)
    before = size()
    block_rates, ids = [], []
    for k in range(trials):
        t, v = _trial_data(seconds, seed=k)
        trial_id = _new_trial(store, study.id, f"B{k}")
        block_rates.append(values_per_trial / _write_blocks(store, trial_id, t, v))
        ids.append(trial_id)
    grown = size() - before
    t, v = _trial_data(seconds, seed=99)
    row_rate = values_per_trial / _write_rows(store, _new_trial(store, study.id, "R"), t, v)
    fsync_rate = values_per_trial / _write_blocks(store, _new_trial(store, study.id, "F"), t, v, durable_flush=True)
    frame = store.read_samples(ids[0])
    expected_t, expected_v = _trial_data(seconds, seed=0)
    if frame.shape != (len(expected_t), len(CHANNELS) + 1) or not np.array_equal(frame.iloc[:, 1:].to_numpy(),
                                                                                   expected_v):
        raise BenchmarkError("benchmark read-back differs from what was written")
    return {
        "write_values_per_s": statistics.median(block_rates),
        "write_values_per_s_rowwise": row_rate,
        "write_values_per_s_fsync_each_flush": fsync_rate,
        "read_trial_ms": _median_ms(lambda: store.read_samples(ids[0]), reads),
        "bytes_per_value": grown / (values_per_trial * trials),
    }


def _sqlite_size(path: Path) -> Callable[[], int]:
    def size() -> int:
        # Checkpoint first: the size at rest, not pages still waiting in the WAL.
        with sqlite3.connect(path) as conn:
            conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        return path.stat().st_size

    return size


def _pg_size(store: StudyStore) -> Callable[[], int]:
    from sqlalchemy import text

    def size() -> int:
        with store.db.engine.connect() as conn:
            return int(conn.execute(text("SELECT pg_total_relation_size('sample_chunk')")).scalar())

    return size


def _narrow_peer(folder: Path, seconds: float, reads: int) -> dict[str, float]:
    """One row per value in SQLite (same pragmas, one commit per second of samples)."""
    path = folder / "narrow.db"
    conn = sqlite3.connect(path, isolation_level=None)
    conn.execute("PRAGMA journal_mode = WAL")
    conn.execute("PRAGMA synchronous = FULL")
    conn.execute("CREATE TABLE sample (trial_id INTEGER, t REAL, channel INTEGER, value REAL)")
    conn.execute("CREATE INDEX ix_sample_trial ON sample (trial_id, t)")
    before = _sqlite_size(path)()
    t, v = _trial_data(seconds, seed=0)
    n_ch = len(CHANNELS)
    start = time.perf_counter()
    for i in range(0, len(t), RATE):
        tt = np.repeat(t[i : i + RATE], n_ch)
        ch = np.tile(np.arange(n_ch), len(t[i : i + RATE]))
        rows = zip([1] * len(tt), tt.tolist(), ch.tolist(), v[i : i + RATE].ravel().tolist(), strict=True)
        conn.execute("BEGIN IMMEDIATE")
        conn.executemany("INSERT INTO sample VALUES (?, ?, ?, ?)", rows)
        conn.execute("COMMIT")
    elapsed = time.perf_counter() - start
    grown = _sqlite_size(path)() - before

    def read() -> pd.DataFrame:
        long = pd.DataFrame(conn.execute("SELECT t, channel, value FROM sample WHERE trial_id = 1").fetchall(),
                            columns=["t", "channel", "value"])
        wide = long.pivot(index="t", columns="channel", values="value")
        wide.columns = CHANNELS
        return wide.reset_index()

    read_ms = _median_ms(read, reads)
    conn.close()
    return {"write_values_per_s": t.size * n_ch / elapsed, "read_trial_ms": read_ms,
            "bytes_per_value": grown / (t.size * n_ch)}


def run(quick: bool = False) -> BenchResult:
    """Measure SQLite and PostgreSQL sample storage (``quick``: 10 s trials, fewer repetitions)."""
    seconds = 10.0 if quick else 90.0
    trials = 1 if quick else 3
    reads = 3 if quick else 9
    notes = [
        f"trial = {seconds:g} s x {RATE} Hz x {len(CHANNELS)} float64 channels; {trials} trial(s) written per "
        "backend, each flush (1 s of samples) one commit, trial completion fsynced; read = median of "
        f"{reads} reads into a DataFrame after one warm-up",
    ]
    figures: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="studyctl-bench-") as tmp:
        folder = Path(tmp)
        path = folder / "bench.db"
        with StudyStore.create(path) as store:
            figures.update(_measure(store, _sqlite_size(path), seconds, trials, reads, "sqlite"))
        peer = _narrow_peer(folder, seconds, reads)
        notes.append("peer: one SQLite row per value (trial_id, t, channel, value), same pragmas and commit "
                     "interval, pivoted to the same wide DataFrame on read")
        pg_url = os.environ.get("STUDYCTL_BENCH_PG")
        if pg_url:
            notes.append("PostgreSQL: the server named by STUDYCTL_BENCH_PG")
            with StudyStore.open(pg_url) as store:
                pg = _measure(store, _pg_size(store), seconds, trials, reads, "pg")
        else:
            from studyctl.store.db import Database
            from studyctl.store.pgserver import ThrowawayPostgres

            notes.append("PostgreSQL: a throwaway local server started for this run (fsync=on, "
                         "synchronous_commit=on), client over TCP loopback, psycopg 3")
            with ThrowawayPostgres(fsync=True) as server:
                with StudyStore(Database.create(server.create_database("bench"))) as store:
                    pg = _measure(store, _pg_size(store), seconds, trials, reads, "pg")
    figures.update({f"pg_{k}": val for k, val in pg.items()})
    figures["pg_read_ratio"] = figures["pg_read_trial_ms"] / figures["read_trial_ms"]
    figures["pg_write_ratio"] = figures["write_values_per_s"] / figures["pg_write_values_per_s"]
    return BenchResult(name="store", figures=figures, peers=peer, notes=notes)
