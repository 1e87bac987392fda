"""``studyctl bench power``: replicate studies per second for the seed-000 study, serial and on Dask.

Each replicate is the whole seed-000 study (bio-inspired palpation, 4 conditions) with N virtual
participants through the real engine into an in-memory database, then the shipped analysis plan
(``simulate_replicate``, exactly what ``studyctl power`` runs). Figures:

* ``replicates_per_s_serial_25`` — 25 participants, one after another in this process;
* ``replicates_per_s_cluster_25`` — 25 participants, a local Dask cluster of worker processes (one per
  core), ``speedup_cluster`` the ratio (the peer of the cluster is the serial run of the same bench);
* scaling with participants (``replicates_per_s_serial_8``, ``seconds_per_participant_*``) and with
  replicates (``replicates_per_s_cluster_8_rK`` after the K-th replicate of one cluster run);
* the two-stage design in the same run (:func:`two_stage_figures`): ``two_stage_pool_build_s`` (a fresh pool of
  20 × n people simulated through the engine, in this process), ``two_stage_replicates_per_s_stage2_N`` (replicate
  studies drawn from it per second) beside ``two_stage_exact_replicates_per_s_N`` (full-engine replicates of
  the same size, its peer), and ``power_error_pp`` (max |two-stage − full-engine power| over the plan's tests at
  that size) with the Monte-Carlo standard errors of both (``mc_se_*_pp_max``);
* the issue's power curve from stored pools (:mod:`studyctl.bench.power_curve`): ``curve_s_bio``/``curve_s_needle``
  and their CPU seconds.

Worker start-up and module imports are excluded (workers and this process are warmed first). The
machine is shared: ``load_1min_start/end`` (``os.getloadavg``) say how busy it was, and
``cpu_s_per_replicate_*`` the CPU time a replicate took in the process that ran it.
"""

from __future__ import annotations

import os
import time
from typing import Any

import pandas as pd

from studyctl.bench import BenchResult

PROTOCOL = "bio_inspired_palpation"
SEED = 0


def _warm() -> str:
    """Import what a replicate uses (engine, plugins, metrics, stats), so timings exclude imports."""
    import studyctl.analysis.execute  # noqa: F401
    import studyctl.analysis.metrics  # noqa: F401
    import studyctl.engine.api  # noqa: F401
    from studyctl.engine.factory import EntryPointFactory
    from studyctl.protocol import load_protocol, resolve_protocol

    protocol = load_protocol(resolve_protocol(PROTOCOL))
    factory = EntryPointFactory()
    for cond in protocol.conditions:
        if cond.controller:
            factory.load("controller", cond.controller)
    factory.load("scene", protocol.scene.plugin)
    factory.load("device", protocol.devices.simulated.plugin)
    factory.load("participant", protocol.participants.virtual.plugin)
    return "warm"


def _timed(backend: Any, spec: Any, tasks: list[tuple[int, int]]) -> tuple[float, list[float], list[Any]]:
    """Run ``tasks`` on ``backend``: total seconds, the time of each completion, the results."""
    stamps: list[float] = []
    results: list[Any] = []
    t0 = time.perf_counter()

    def keep(result: Any) -> None:
        stamps.append(time.perf_counter() - t0)
        results.append(result)

    backend.run(spec, tasks, keep)
    return time.perf_counter() - t0, stamps, results


#: The two-stage part runs at n = 4 (one person per Williams sequence): a 20 × 4 = 80-person pool is what this
#: loaded 2-core machine can simulate inside a bench; larger n need proportionally larger pools.
TWO_STAGE_N = 4
#: Replicate studies of the issue's power curve (5 sample sizes × 1,000 replicates).
CURVE_REPLICATES = 5 * 1000


def two_stage_figures(quick: bool, protocol: str = PROTOCOL, plan: str = PROTOCOL, n: int = TWO_STAGE_N,
                      seed: int = SEED) -> tuple[dict[str, float], list[dict[str, Any]], list[str]]:
    """Build a fresh pool, time stage 2, and compare its power with full-engine replicates (see the module docs).

    ``protocol``/``plan``/``n``/``seed`` are the seed-000 study's by default (other values: tests)."""
    import tempfile

    from studyctl.bench.power_curve import cli_spec
    from studyctl.power.executor import SerialBackend
    from studyctl.power.pool import MIN_POOL_FACTOR, build_pool
    from studyctl.power.summary import summarise
    from studyctl.power.twostage import Stage2, compare

    stage2_reps, exact_reps = (20, 2) if quick else (400, 20)
    spec = cli_spec(protocol, plan, (n,), stage2_reps, seed)
    with tempfile.TemporaryDirectory(prefix="studyctl-bench-pool-") as folder:
        t0, c0 = time.perf_counter(), time.process_time()
        pool = build_pool(spec, folder, MIN_POOL_FACTOR * n)
        build_s, build_cpu = time.perf_counter() - t0, time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    # the pool's per-person frames and units are prepared once per run (counted in the stage-2 time)
    stage2 = Stage2(spec, pool)
    drawn = [stage2.replicate(n, r) for r in range(stage2_reps)]
    s2_s, s2_cpu = time.perf_counter() - t0, time.process_time() - c0
    exact, _, done = _timed(SerialBackend(None), spec, [(n, r) for r in range(exact_reps)])
    frame = lambda results: pd.concat([r.to_frame() for r in results], ignore_index=True)  # noqa: E731
    two = summarise(frame(drawn), (n,), stage2_reps).frame
    ref = summarise(frame(done), (n,), exact_reps).frame
    err = compare(two, ref, (n,)).summary()
    figures = {
        "two_stage_pool_people": float(pool.size),
        "two_stage_pool_build_s": build_s,
        "two_stage_pool_build_cpu_s": build_cpu,
        f"two_stage_replicates_per_s_stage2_{n}": stage2_reps / s2_s,
        f"two_stage_cpu_s_per_replicate_stage2_{n}": s2_cpu / stage2_reps,
        f"two_stage_exact_replicates_per_s_{n}": exact_reps / exact,
        f"two_stage_exact_cpu_s_per_replicate_{n}": sum(r.cpu_seconds for r in done) / exact_reps,
        # the curve (5 sizes × 1,000 replicates) at this run's stage-2 rate: a projection from the rate
        # measured at this n (larger n cost somewhat more per replicate), not a timed curve
        f"curve_s_projected_5x1000_at_{n}": CURVE_REPLICATES / (stage2_reps / s2_s),
        f"curve_cpu_s_projected_5x1000_at_{n}": CURVE_REPLICATES * s2_cpu / stage2_reps,
        "power_error_pp": err["power_error_pp"],
        "power_error_mc_se_exact_pp_max": err["mc_se_exact_pp_max"],
        "power_error_mc_se_two_stage_pp_max": err["mc_se_two_stage_pp_max"],
        "power_error_exact_replicates": float(exact_reps),
        "power_error_two_stage_replicates": float(stage2_reps),
    }
    rows = [{"backend": "two-stage pool (serial)", "participants": pool.size, "replicates": 1, "seconds": build_s,
             "replicates_per_s": None},
            {"backend": "two-stage stage 2 (serial)", "participants": n, "replicates": stage2_reps, "seconds": s2_s,
             "replicates_per_s": stage2_reps / s2_s},
            {"backend": "full engine (serial, two-stage check)", "participants": n, "replicates": exact_reps,
             "seconds": exact, "replicates_per_s": exact_reps / exact}]
    notes = [f"two-stage at n = {n}: a fresh {pool.size}-person pool ({MIN_POOL_FACTOR} × n, chunks of "
             f"{pool.chunk_size}) built serially here; {stage2_reps} stage-2 replicates vs {exact_reps} full-engine "
             f"replicates (peer of the stage-2 rate); power_error_pp is the max over the plan's tests; with "
             f"{exact_reps} full-engine replicates its MC error (mc_se_*) is far above 2 pp: not a validation "
             "of the issue's ≤ 2 pp goal"]
    return figures, rows, notes


def cluster_keys(big: int, small: int, per_cluster: int, workers: int = 2) -> list[str]:
    """The figures only a local cluster of ``workers`` measures (null when the bench runs with ``--workers 1``)."""
    return [f"replicates_per_s_cluster_{big}", f"cpu_s_per_replicate_cluster_{big}", f"cores_used_cluster_{big}",
            *(f"replicates_per_s_cluster_{small}_r{k}" for k in range(workers, per_cluster + 1, workers)),
            "speedup_cluster", "cpu_efficiency_cluster", "cluster_startup_s"]


def _cluster_figures(spec: Any, big: int, small: int, per_cluster: int, workers: int,
                     rows: list[dict[str, Any]], serial: dict[str, float]) -> dict[str, float]:
    """Time the same replicates on a local Dask cluster of ``workers`` processes; ``serial`` holds this run's
    serial figures (the cluster's peer), ``rows`` gets the table rows."""
    from studyctl.power.executor import DaskBackend

    figures: dict[str, float] = {}
    t_start = time.perf_counter()
    cluster = DaskBackend.local(workers, None)
    try:
        figures["cluster_startup_s"] = time.perf_counter() - t_start
        cluster.client.run(_warm)
        c_big, _, rc_big = _timed(cluster, spec, [(big, r) for r in range(workers)])
        figures[f"replicates_per_s_cluster_{big}"] = workers / c_big
        figures[f"cpu_s_per_replicate_cluster_{big}"] = sum(r.cpu_seconds for r in rc_big) / len(rc_big)
        figures[f"cores_used_cluster_{big}"] = sum(r.cpu_seconds for r in rc_big) / c_big
        rows.append({"backend": f"local cluster ({workers} workers)", "participants": big, "replicates": workers,
                     "seconds": c_big, "replicates_per_s": workers / c_big})
        c_small, stamps, _ = _timed(cluster, spec, [(small, r) for r in range(per_cluster)])
        for k in range(workers, per_cluster + 1, workers):
            rate = k / stamps[k - 1]
            figures[f"replicates_per_s_cluster_{small}_r{k}"] = rate
            rows.append({"backend": f"local cluster ({workers} workers)", "participants": small, "replicates": k,
                         "seconds": stamps[k - 1], "replicates_per_s": rate})
    finally:
        cluster.close()
    figures["speedup_cluster"] = figures[f"replicates_per_s_cluster_{big}"] / serial[f"replicates_per_s_serial_{big}"]
    # The same ratio in CPU time (replicates per CPU-second): 1.0 means the workers waste nothing; the wall-time
    # speedup is then bounded by how many cores the machine gave the cluster (cores_used_cluster_*).
    figures["cpu_efficiency_cluster"] = (serial[f"cpu_s_per_replicate_serial_{big}"]
                                         / figures[f"cpu_s_per_replicate_cluster_{big}"])
    return figures


def run(quick: bool = False, workers: int | None = None) -> BenchResult:
    """Measure replicates per second (see the module docs); ``quick`` uses 4 participants throughout.

    ``workers``: processes of the local cluster (default one per core). 1 runs everything serially in this
    process and starts no cluster (a shared machine): the cluster figures are then null, and the notes say so."""
    from studyctl.bench.power_curve import cli_spec
    from studyctl.power.executor import SerialBackend
    from studyctl.report.loop_rates import loop_rates_line

    big, small, per_cluster = (4, 4, 2) if quick else (25, 8, 4)
    asked = workers
    workers = workers or os.cpu_count() or 1
    load_start = os.getloadavg()[0]
    spec = cli_spec(PROTOCOL, PROTOCOL, (small, big) if small != big else (big,), 1, SEED)
    _warm()
    serial = SerialBackend(None)
    figures: dict[str, float] = {}
    rows: list[dict[str, Any]] = []

    s_big, _, r_big = _timed(serial, spec, [(big, 0)])
    figures[f"replicates_per_s_serial_{big}"] = 1.0 / s_big
    figures[f"cpu_s_per_replicate_serial_{big}"] = r_big[0].cpu_seconds
    # CPU seconds our processes got per wall second: 1.0 is one whole core; on an idle 2-core machine a
    # 2-worker cluster gets ~2. On a shared machine this says how much of the cores the run really had.
    figures[f"cores_used_serial_{big}"] = r_big[0].cpu_seconds / s_big
    rows.append({"backend": "serial", "participants": big, "replicates": 1, "seconds": s_big,
                 "replicates_per_s": 1.0 / s_big})
    if small != big:
        s_small, _, r_small = _timed(serial, spec, [(small, 0)])
        figures[f"replicates_per_s_serial_{small}"] = 1.0 / s_small
        figures[f"cpu_s_per_replicate_serial_{small}"] = r_small[0].cpu_seconds
        figures[f"seconds_per_participant_serial_{small}"] = s_small / small
        rows.append({"backend": "serial", "participants": small, "replicates": 1, "seconds": s_small,
                     "replicates_per_s": 1.0 / s_small})
    figures[f"seconds_per_participant_serial_{big}"] = s_big / big

    if workers > 1:
        figures.update(_cluster_figures(spec, big, small, per_cluster, workers, rows, figures))
    else:
        # null, not a guess: one worker would only time the serial path again, plus a scheduler
        figures.update(dict.fromkeys(cluster_keys(big, small, per_cluster), None))
    figures["workers"] = float(workers)
    figures["load_1min_start"] = load_start
    figures["load_1min_end"] = os.getloadavg()[0]
    # the serial run is the cluster's peer in this run
    peers = {f"replicates_per_s_cluster_{big}": figures[f"replicates_per_s_serial_{big}"]} if workers > 1 else {}
    notes = [
        f"seed-000 study ({PROTOCOL}), master seed {SEED}; each replicate = N virtual participants' whole "
        "sessions through the engine into an in-memory SQLite store + the shipped analysis plan; "
        f"{loop_rates_line(spec.loop_rates(), spec.sim_rate_hz)}, as studyctl power runs it by default",
        (f"local cluster: {workers} single-threaded worker processes on 127.0.0.1 (os.cpu_count() = "
         f"{os.cpu_count()}); start-up and imports excluded (cluster_startup_s given separately); peer of "
         "replicates_per_s_cluster_* = the serial run in this process, same bench run" if workers > 1 else
         "--workers 1: serial only, no Dask cluster started (a shared machine); the cluster figures "
         f"({', '.join(cluster_keys(big, small, per_cluster))}) are null, not measured, and the curve's stage 2 "
         "runs serially in this process"),
        f"machine load (1-min average) {load_start:.1f} at start, {figures['load_1min_end']:.1f} at end, on "
        f"{workers} cores: other processes share the cores, so wall-time rates and the speedup depend on it",
    ]
    ts_figures, ts_rows, ts_notes = two_stage_figures(quick)
    figures.update(ts_figures)
    rows += ts_rows
    notes += ts_notes
    # the full-engine replicates of the same size, same run, are the stage-2 rate's peer
    peers[f"two_stage_replicates_per_s_stage2_{TWO_STAGE_N}"] = ts_figures[
        f"two_stage_exact_replicates_per_s_{TWO_STAGE_N}"]
    # the curve (5 sizes × 1,000 stage-2 replicates per protocol) from the stored pools, same run
    from studyctl.bench.power_curve import run as curve_run

    # --workers 1 runs the curve's stage 2 serially too; unasked, the curve keeps its own setting
    curve = curve_run(quick, workers=asked)
    figures.update({k: v for k, v in curve.figures.items() if not k.startswith("load_")})
    peers.update(curve.peers)
    rows += curve.tables.get("runs", [])
    notes += curve.notes
    figures["load_1min_end"] = os.getloadavg()[0]
    if quick:
        notes.append("--quick: 4 participants (the 4 counterbalancing sequences) instead of 25; a smoke run")
    return BenchResult(name="power", figures=figures, peers=peers, tables={"runs": rows}, notes=notes)
