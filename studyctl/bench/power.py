"""``studyctl bench power``: replicate studies per second for the seed-000 study, serial and on Dask.

Each replicate is the whole seed-000 study (bio-inspired palpation, 4 conditions) with N virtual
participants through the real engine into an in-memory database, then the shipped analysis plan
(``simulate_replicate``, exactly what ``studyctl power`` runs). Figures:

* ``replicates_per_s_serial_25`` — 25 participants, one after another in this process;
* ``replicates_per_s_cluster_25`` — 25 participants, a local Dask cluster of worker processes (one per
  core), ``speedup_cluster`` the ratio (the peer of the cluster is the serial run of the same bench);
* scaling with participants (``replicates_per_s_serial_8``, ``seconds_per_participant_*``) and with
  replicates (``replicates_per_s_cluster_8_rK`` after the K-th replicate of one cluster run).

Worker start-up and module imports are excluded (workers and this process are warmed first). The
machine is shared: ``load_1min_start/end`` (``os.getloadavg``) say how busy it was, and
``cpu_s_per_replicate_*`` the CPU time a replicate took in the process that ran it.
"""

from __future__ import annotations

import os
import time
from typing import Any

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


def run(quick: bool = False) -> BenchResult:
    """Measure replicates per second (see the module docs); ``quick`` uses 4 participants throughout."""
    from studyctl.power import prepare_power
    from studyctl.power.executor import DaskBackend, SerialBackend

    big, small, per_cluster = (4, 4, 2) if quick else (25, 8, 4)
    workers = os.cpu_count() or 1
    load_start = os.getloadavg()[0]
    spec = prepare_power(PROTOCOL, PROTOCOL, sizes=(small, big) if small != big else (big,), replicates=1, seed=SEED)
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

    t_start = time.perf_counter()
    cluster = DaskBackend.local(workers, None)
    try:
        startup = time.perf_counter() - t_start
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
    figures["speedup_cluster"] = figures[f"replicates_per_s_cluster_{big}"] / figures[f"replicates_per_s_serial_{big}"]
    # The same ratio in CPU time (replicates per CPU-second): 1.0 means the workers waste nothing; the wall-time
    # speedup is then bounded by how many cores the machine gave the cluster (cores_used_cluster_*).
    figures["cpu_efficiency_cluster"] = (figures[f"cpu_s_per_replicate_serial_{big}"]
                                         / figures[f"cpu_s_per_replicate_cluster_{big}"])
    figures["workers"] = float(workers)
    figures["cluster_startup_s"] = startup
    figures["load_1min_start"] = load_start
    figures["load_1min_end"] = os.getloadavg()[0]
    # the serial run is the cluster's peer in this run
    peers = {f"replicates_per_s_cluster_{big}": figures[f"replicates_per_s_serial_{big}"]}
    notes = [
        f"seed-000 study ({PROTOCOL}), master seed {SEED}; each replicate = N virtual participants' whole "
        "sessions through the engine into an in-memory SQLite store + the shipped analysis plan",
        f"local cluster: {workers} single-threaded worker processes on 127.0.0.1 (os.cpu_count() = {workers}); "
        "start-up and imports excluded (cluster_startup_s given separately)",
        "peer of replicates_per_s_cluster_* = the serial run in this process, same bench run",
        f"machine load (1-min average) {load_start:.1f} at start, {figures['load_1min_end']:.1f} at end, on "
        f"{workers} cores: other processes share the cores, so wall-time rates and the speedup depend on it",
    ]
    if quick:
        notes.append("--quick: 4 participants (the 4 counterbalancing sequences) instead of 25; a smoke run")
    return BenchResult(name="power", figures=figures, peers=peers, tables={"runs": rows}, notes=notes)
