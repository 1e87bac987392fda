"""``studyctl bench power_curve``: the issue's power curve (5 sample sizes × 1,000 replicates) by the two-stage design,
for seed 000 and seed 001, from stored pools of their shipped (calibrated) populations.

The pool (stage 1: people simulated through the full engine) is built once and stored; this bench times stage 2,
the part a power curve repeats, as ``studyctl power --two-stage`` runs it: batches of replicates as tasks on a local
Dask cluster of ``$STUDYCTL_BENCH_WORKERS`` workers (default 2; 0: serially in this process). ``curve_s_<protocol>``
is its wall time, ``curve_cpu_s_<protocol>`` the replicates' CPU seconds summed over the workers,
``stage2_overhead_pct_<protocol>`` the share of the workers' wall time spent outside replicates (scheduling,
transfers, each worker's one pool load), beside the pool's own build cost as stored with it
(``pool_build_cpu_s_<protocol>``, summed over its chunks) and, as the peer, the full-engine CPU seconds per
replicate of the same study measured in the same run (one replicate at the smallest size).

Pools come from ``$STUDYCTL_BENCH_POOL_DIR`` (default ``reports/power-pools``, where ``studyctl power --two-stage``
keeps them): the largest pool file of each protocol there. Stage-2 timing does not depend on how the pool's people
were simulated, so a pool built by an earlier code version or at another loop rate is used as it is (its key and rate
are in the notes). The peer's full-engine replicate runs at the loop rates ``studyctl power`` uses by default
(:func:`cli_spec`: seed 001's 1 kHz needle loop at 250 Hz, seed 000's 50 Hz loops as they are); ``loop_rate_hz_<tag>``
says the fastest loop it simulated. The sizes
are the default ones when the pool holds 20 × their largest, else the five largest block-completing sizes it
holds 20 × of; a pool too small even for that is used for timing only and the notes say so. ``--quick``: 50
replicates per size."""

from __future__ import annotations

import json
import math
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


def _sizes(default: tuple[int, ...], people: int) -> tuple[tuple[int, ...], bool]:
    """The curve's sizes: the default ones when the pool holds 20 × their largest, else five evenly spaced sizes
    from the smallest default one to the largest the pool holds 20 × of (False: the pool holds too few even for
    that; the default sizes are then timed only)."""
    from studyctl.power.pool import MIN_POOL_FACTOR

    top, low = people // MIN_POOL_FACTOR, min(default)
    if top >= max(default):
        return default, True
    if top < low + 4:
        return default, False
    return tuple(sorted({round(low + (top - low) * k / 4) for k in range(5)})), True


def _stage2(spec: Any, path: Path, chunks: int, size: int, todo: list[tuple[int, int]], workers: int) -> dict:
    """Run the stage-2 replicates ``todo`` as ``studyctl power --two-stage`` does: serially (workers 0) or as
    batches of replicates on a local Dask cluster; wall, summed replicate CPU and busy seconds."""
    from studyctl.power.twostage import batches, draw_batch

    out: list[Any] = []
    keep = lambda r: out.extend(r)  # noqa: E731 - a batch's list of replicates
    if workers == 0:
        t0 = time.perf_counter()
        for n, a, b in batches(todo, len(todo)):
            keep(draw_batch(spec, str(path), chunks, size, n, a, b))
        wall, start_s = time.perf_counter() - t0, 0.0
    else:
        from studyctl.power.executor import DaskBackend
        from studyctl.workflows.power_two_stage import STAGE2_BATCH

        s0 = time.perf_counter()
        backend = DaskBackend.local(workers, None)
        start_s = time.perf_counter() - s0
        try:
            per_task = max(1, min(STAGE2_BATCH, math.ceil(len(todo) / (4 * workers))))
            tasks = [(str(path), chunks, size, n, a, b) for n, a, b in batches(todo, per_task)]
            t0 = time.perf_counter()
            backend.map(draw_batch, spec, tasks, keep, tag="bench")
            wall = time.perf_counter() - t0
        finally:
            backend.close()
    busy = sum(r.seconds for r in out)
    return {"wall": wall, "cpu": sum(r.cpu_seconds for r in out), "busy": busy, "count": len(out),
            "start_s": start_s, "tasks": len(todo) if workers == 0 else len(tasks),
            # what the workers' slots spent outside replicates (scheduling, transfers, each worker's pool load)
            "overhead_pct": 100.0 * (1.0 - busy / (max(workers, 1) * wall)) if wall > 0 else math.nan}


def cli_spec(protocol: str, plan: str, sizes: tuple[int, ...], replicates: int, seed: int | None) -> Any:
    """The power spec ``studyctl power PROTOCOL --plan PLAN`` runs by default (shipped population,
    the rate-adjustable loops capped at the CLI's default rate,
    :func:`studyctl.engine.loop_rates.default_sim_rate`), so a bench times what users get."""
    from studyctl.engine.loop_rates import default_sim_rate
    from studyctl.power import prepare_power
    from studyctl.protocol import load_protocol, resolve_protocol

    loaded = load_protocol(resolve_protocol(protocol))
    return prepare_power(loaded, plan, sizes=sizes, replicates=replicates, seed=seed,
                         sim_rate_hz=default_sim_rate(loaded))


def curve(protocol: str, sizes: tuple[int, ...], replicates: int, folder: Path,
          workers: int = 2) -> tuple[dict, list, list]:
    from studyctl.power.executor import SerialBackend
    from studyctl.report.loop_rates import loop_rates_line

    found = _largest_pool(folder, protocol)
    if found is None:
        return {}, [], [f"{protocol}: no pool in {folder}; build one with studyctl power {protocol} --two-stage "
                        f"--pool-dir {folder}"]
    path, chunks, size, key = found
    people = chunks * size
    sizes, valid = _sizes(sizes, people)
    spec = cli_spec(protocol, protocol, sizes, replicates, key["seed"])
    todo = [(n, r) for n in sizes for r in range(replicates)]
    run = _stage2(spec, path, chunks, size, todo, workers)
    with sqlite3.connect(path) as c:
        build_cpu = c.execute("SELECT COALESCE(SUM(cpu_seconds), 0) FROM chunks WHERE chunk < ?",
                              (chunks,)).fetchone()[0]
    # the peer: one full-engine replicate of the same study at the smallest size, same run
    e0 = time.perf_counter()
    done: list[Any] = []
    SerialBackend(None).run(spec, [(sizes[0], 0)], done.append)
    exact_wall = time.perf_counter() - e0
    total, wall, cpu = run["count"], run["wall"], run["cpu"]
    tag = protocol.split("_")[0]
    figures = {
        f"curve_s_{tag}": wall, f"curve_cpu_s_{tag}": cpu, f"curve_replicates_{tag}": float(total),
        f"stage2_replicates_per_s_{tag}": total / wall, f"stage2_cpu_s_per_replicate_{tag}": cpu / total,
        f"stage2_workers_{tag}": float(workers), f"stage2_overhead_pct_{tag}": run["overhead_pct"],
        f"stage2_tasks_{tag}": float(run["tasks"]), f"cluster_start_s_{tag}": run["start_s"],
        f"pool_people_{tag}": float(people), f"pool_build_cpu_s_{tag}": float(build_cpu),
        f"exact_cpu_s_per_replicate_{tag}_n{sizes[0]}": done[0].cpu_seconds,
        f"exact_s_per_replicate_{tag}_n{sizes[0]}": exact_wall,
        f"loop_rate_hz_{tag}": max(spec.loop_rates().values(), default=math.nan),
    }
    pool_rate = "the protocol's rates" if key.get("sim_rate_hz") is None else f"{key['sim_rate_hz']:g} Hz"
    rows = [{"protocol": protocol, "sizes": ",".join(map(str, sizes)), "replicates": total, "seconds": wall,
             "cpu_seconds": cpu, "workers": workers, "overhead_pct": run["overhead_pct"], "pool": people}]
    notes = [f"{protocol}: {people}-person pool {path.name} (seed {key['seed']}, code "
             f"{str(key.get('code_sha256'))[:12]}, population {str(key.get('traits_sha256'))[:12]}, simulated at "
             f"{pool_rate}); sizes "
             f"{', '.join(map(str, sizes))}; full-engine peer's {loop_rates_line(spec.loop_rates(), spec.sim_rate_hz)}"
             + ("" if valid else f"; below 20 × {max(sizes)}: timing only, not a valid power curve")]
    return figures, rows, notes


def run(quick: bool = False, workers: int | None = None) -> BenchResult:
    """Time the curves (see the module docs). ``workers`` (``studyctl bench --workers``) overrides
    ``$STUDYCTL_BENCH_WORKERS``; as there, 1 means serially in this process, no cluster (the variable's 0)."""
    folder = Path(os.environ.get("STUDYCTL_BENCH_POOL_DIR", "reports/power-pools")).expanduser()
    if workers is None:
        workers = int(os.environ.get("STUDYCTL_BENCH_WORKERS", "2"))
    elif workers == 1:
        workers = 0
    replicates = 50 if quick else REPLICATES
    load_start = os.getloadavg()[0]
    figures: dict[str, float] = {"replicates_per_size": float(replicates), "load_1min_start": load_start}
    rows: list[dict] = []
    notes = [(f"stage 2 on a local Dask cluster of {workers} workers, batches of replicates per task (as studyctl "
              "power --two-stage runs it)" if workers else "stage 2 serial in this process")
             + f"; 5 sizes × {replicates} replicates per protocol; pool build is the stored one-off cost (chunks' "
             "CPU seconds), not part of curve_s; overhead_pct: share of the workers' wall time outside replicates",
             f"2 cores, load (1-min) {load_start:.1f} at start: wall time depends on it, CPU seconds much less"]
    peers: dict[str, float] = {}
    for protocol, sizes in CURVES:
        f, r, n = curve(protocol, sizes, replicates, folder, workers)
        figures.update(f)
        rows += r
        notes += n
        tag = protocol.split("_")[0]
        if f:
            peers[f"stage2_cpu_s_per_replicate_{tag}"] = next(v for k, v in f.items() if k.startswith("exact_cpu"))
    figures["load_1min_end"] = os.getloadavg()[0]
    if quick:
        notes.append("--quick: 50 replicates per size; curve_s is then not the issue's 5 × 1,000")
    return BenchResult(name="power_curve", figures=figures, peers=peers, tables={"runs": rows}, notes=notes)
