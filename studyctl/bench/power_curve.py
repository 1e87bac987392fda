"""``studyctl bench power_curve``: the issue's power curve (5 sample sizes × 1,000 replicates) by the two-stage design,
for seed 000 and seed 001, from stored pools of their shipped (calibrated) populations.

The pool (stage 1: people simulated through the full engine) is built once and stored; this bench times stage 2,
the part a power curve repeats: ``curve_s_<protocol>`` is the wall time of 5 × 1,000 stage-2 replicates in this
process (serial), ``curve_cpu_s_<protocol>`` its CPU seconds, beside the pool's own build cost as stored with it
(``pool_build_cpu_s_<protocol>``, summed over its chunks) and, as the peer, the full-engine CPU seconds per
replicate of the same study measured in the same run (one replicate at the smallest size).

Pools come from ``$STUDYCTL_BENCH_POOL_DIR`` (default ``reports/power-pools``, where ``studyctl power --two-stage``
keeps them): the largest pool file of each protocol there. Stage-2 timing does not depend on how the pool's people
were simulated, so a pool built by an earlier code version is used as it is (its key is in the notes); a pool
below 20 × the largest size is used for timing only and the notes say so. ``--quick``: 50 replicates per size.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from pathlib import Path
from typing import Any

from studyctl.bench import BenchResult

#: (protocol, sample sizes): the CLI's default sizes for seed 000; seed 001's people cost ~5 CPU s each, so its
#: pool here is smaller and so are its sizes (every one ≥ the protocol's counterbalancing sequences).
CURVES = (("bio_inspired_palpation", (8, 12, 16, 20, 25)), ("needle_insertion", (4, 6, 8, 10, 12)))
REPLICATES = 1000


def _largest_pool(folder: Path, protocol: str) -> tuple[Path, int, int, dict] | None:
    best = None
    for path in sorted(folder.glob(f"{protocol}-*.sqlite")):
        with sqlite3.connect(path) as c:
            chunks = c.execute("SELECT COUNT(*) FROM chunks").fetchone()[0]
            key = json.loads(c.execute("SELECT value FROM meta WHERE key = 'key'").fetchone()[0])
            # only a pool whose chunks are 0 … k-1 (a build that stopped midway keeps a prefix)
            top = c.execute("SELECT COALESCE(MAX(chunk), -1) FROM chunks").fetchone()[0]
        if chunks and top == chunks - 1 and (best is None or chunks * key["chunk_size"] > best[1] * best[2]):
            best = (path, chunks, int(key["chunk_size"]), key)
    return best


def curve(protocol: str, sizes: tuple[int, ...], replicates: int, folder: Path) -> tuple[dict, list, list]:
    from studyctl.power import prepare_power
    from studyctl.power.executor import SerialBackend
    from studyctl.power.pool import MIN_POOL_FACTOR, PoolFile
    from studyctl.power.seeds import draw_rng
    from studyctl.power.twostage import Stage2, composition, draw_members

    found = _largest_pool(folder, protocol)
    if found is None:
        return {}, [], [f"{protocol}: no pool in {folder}; build one with studyctl power {protocol} --two-stage "
                        f"--pool-dir {folder}"]
    path, chunks, size, key = found
    pf = PoolFile(path, sqlite3.connect(path))
    try:
        pool = pf.load(chunks, size, 0)
    finally:
        pf.close()
    spec = prepare_power(protocol, protocol, sizes=sizes, replicates=replicates, seed=key["seed"])
    t0, c0 = time.perf_counter(), time.process_time()
    stage2 = Stage2(spec, pool)
    for n in sizes:
        for r in range(replicates):
            stage2.rows(draw_members(pool, composition(stage2.protocol, spec.seed, n, r), draw_rng(spec.seed, n, r)))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    # the peer: one full-engine replicate of the same study at the smallest size, same run
    e0 = time.perf_counter()
    done: list[Any] = []
    SerialBackend(None).run(spec, [(sizes[0], 0)], done.append)
    exact_wall = time.perf_counter() - e0
    total = len(sizes) * replicates
    tag = protocol.split("_")[0]
    figures = {
        f"curve_s_{tag}": wall, f"curve_cpu_s_{tag}": cpu, f"curve_replicates_{tag}": float(total),
        f"stage2_replicates_per_s_{tag}": total / wall, f"stage2_cpu_s_per_replicate_{tag}": cpu / total,
        f"pool_people_{tag}": float(pool.size), f"pool_build_cpu_s_{tag}": pool.build_cpu_seconds,
        f"exact_cpu_s_per_replicate_{tag}_n{sizes[0]}": done[0].cpu_seconds,
        f"exact_s_per_replicate_{tag}_n{sizes[0]}": exact_wall,
    }
    rows = [{"protocol": protocol, "sizes": ",".join(map(str, sizes)), "replicates": total, "seconds": wall,
             "cpu_seconds": cpu, "pool": pool.size}]
    small = pool.size < MIN_POOL_FACTOR * max(sizes)
    notes = [f"{protocol}: {pool.size}-person pool {path.name} (seed {key['seed']}, code "
             f"{str(key.get('code_sha256'))[:12]}, population {str(key.get('traits_sha256'))[:12]})"
             + (f"; below {MIN_POOL_FACTOR} × {max(sizes)}: timing only, not a valid power curve" if small else "")]
    return figures, rows, notes


def run(quick: bool = False) -> BenchResult:
    folder = Path(os.environ.get("STUDYCTL_BENCH_POOL_DIR", "reports/power-pools")).expanduser()
    replicates = 50 if quick else REPLICATES
    load_start = os.getloadavg()[0]
    figures: dict[str, float] = {"replicates_per_size": float(replicates), "load_1min_start": load_start}
    rows: list[dict] = []
    notes = [f"stage 2 serial in this process; 5 sizes × {replicates} replicates per protocol; pool build is the "
             "stored one-off cost (chunks' CPU seconds), not part of curve_s",
             f"2 cores, load (1-min) {load_start:.1f} at start: wall time depends on it, CPU seconds much less"]
    peers: dict[str, float] = {}
    for protocol, sizes in CURVES:
        f, r, n = curve(protocol, sizes, replicates, folder)
        figures.update(f)
        rows += r
        notes += n
        tag = protocol.split("_")[0]
        if f:
            peers[f"stage2_cpu_s_per_replicate_{tag}"] = f[f"exact_cpu_s_per_replicate_{tag}_n{sizes[0]}"]
    figures["load_1min_end"] = os.getloadavg()[0]
    if quick:
        notes.append("--quick: 50 replicates per size; curve_s is then not the issue's 5 × 1,000")
    return BenchResult(name="power_curve", figures=figures, peers=peers, tables={"runs": rows}, notes=notes)
