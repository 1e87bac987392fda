"""One evaluation of ``studyctl calibrate``: a candidate population run as the calibration's simulated studies
(the same seeds for every candidate), on local worker processes or a Dask scheduler, and its distance to the fit
targets. :mod:`studyctl.workflows.calibrate` searches over these evaluations.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd

from studyctl.calibration import distance, simulated_values
from studyctl.calibration.simulated import SimulatedStats, SimulatedValue
from studyctl.errors import SessionInterrupted, StudyctlError, UsageError
from studyctl.workflows.calibration_spec import CalibrationSpec


@dataclass(frozen=True)
class Evaluation:
    """One candidate population run as the calibration's simulated studies."""

    values: dict[str, float]
    distance: float
    z: dict[str, float]
    stats: pd.DataFrame  # SimulatedStats.to_frame()
    seconds: float
    cpu_seconds: float
    participants: int


def _replicate_task(power_spec: Any, participants: int, replicate: int) -> tuple[pd.DataFrame, pd.DataFrame, float]:
    """One simulated study (a Dask task): its metric frame, test rows and CPU seconds."""
    from studyctl.power.replicate import simulate_replicate

    tables: list[Any] = []
    res = simulate_replicate(power_spec, participants, replicate, on_metrics=tables.append)
    frame = tables[0].frame.copy()
    frame["participant"] = f"r{replicate}:" + frame["participant"].astype(str)
    return frame, res.to_frame(), res.cpu_seconds


def _power_spec(spec: CalibrationSpec, pop: Any) -> Any:
    from studyctl.power.population import Population
    from studyctl.power.spec import PowerSpec

    return PowerSpec(
        protocol_name=spec.protocol_id, protocol_text=spec.protocol_text,
        protocol_sha256=hashlib.sha256(spec.protocol_text.encode()).hexdigest(), study_id=spec.protocol_id,
        plan=spec.plan, plan_sha256="", population=Population(), seed=spec.seed, sizes=(spec.participants,),
        replicates=spec.replicates, sequences=None, traits=pop, sim_rate_hz=spec.sim_rate_hz,
    )


FAILED_DISTANCE = 1e6  # a candidate whose simulated studies fail (a participant refuses its values …)


def evaluate(spec: CalibrationSpec, values: dict[str, float], *, participants: int | None = None,
             targets: Sequence[Any] | None = None, sim_se: dict[str, float] | None = None,
             client: Any | None = None) -> Evaluation:
    """Run the candidate ``values`` as the calibration's simulated studies (the same seeds every time).

    A candidate whose simulation fails with a studyctl error (e.g. the participant refuses a value) gets the
    distance :data:`FAILED_DISTANCE` and the error as a note, so the search goes on elsewhere."""
    try:
        return _evaluate(spec, values, participants=participants, targets=targets, sim_se=sim_se, client=client)
    except SessionInterrupted:
        raise
    except StudyctlError as exc:
        targets = list(targets if targets is not None else spec.targets.targets)
        stats = SimulatedStats(tuple(SimulatedValue(t.id, t.statistic, math.nan, note=f"simulation failed: {exc}")
                                     for t in targets))
        return Evaluation(dict(values), FAILED_DISTANCE, {t.id: math.nan for t in targets}, stats.to_frame(),
                          0.0, 0.0, participants or spec.participants)


def _evaluate(spec: CalibrationSpec, values: dict[str, float], *, participants: int | None,
              targets: Sequence[Any] | None, sim_se: dict[str, float] | None, client: Any | None) -> Evaluation:
    from studyctl.populations.free import apply_values

    t0 = time.perf_counter()
    n = participants or spec.participants
    pop = apply_values(spec.population, values, spec.free)
    pspec = _power_spec(spec, pop)
    if client is not None:
        futures = [client.submit(_replicate_task, pspec, n, r, pure=False) for r in range(spec.replicates)]
        parts = client.gather(futures)
    elif spec.workers > 1 and spec.replicates > 1:
        from concurrent.futures.process import BrokenProcessPool

        try:
            parts = list(_pool(spec.workers).map(_replicate_task, [pspec] * spec.replicates,
                                                 [n] * spec.replicates, range(spec.replicates)))
        except BrokenProcessPool:
            raise SessionInterrupted("a calibration worker process ended (interrupted or killed); the journal keeps "
                                     "every finished evaluation: run the same command again to continue") from None
    else:
        parts = [_replicate_task(pspec, n, r) for r in range(spec.replicates)]
    metrics = pd.concat([p[0] for p in parts], ignore_index=True)
    targets = list(targets if targets is not None else spec.targets.targets)
    descriptive = [t for t in targets if not t.is_test]
    tests = [t for t in targets if t.is_test]
    rng = np.random.default_rng(spec.seed)
    stats = simulated_values(descriptive, metrics, parts[0][1], alpha=spec.targets.alpha, rng=rng)
    values_all = list(stats.values)
    for t in tests:  # per replicate: the median p, the majority verdict
        per = [simulated_values([t], p[0], p[1], alpha=spec.targets.alpha, rng=rng).values[0] for p in parts]
        ok = [v for v in per if not (isinstance(v.value, float) and math.isnan(v.value))]
        if not ok:
            values_all.append(per[0])
        elif t.statistic == "verdict":
            share = sum(bool(v.value) for v in ok) / len(ok)
            ways = [v.higher for v in ok if v.higher]  # a stated direction: the replicates' most common one
            higher = max(sorted(set(ways)), key=ways.count) if ways else ""
            values_all.append(replace(ok[0], value=share >= 0.5, higher=higher,
                                      note=f"significant in {share:.0%} of {len(ok)} simulated studies; {ok[0].note}"))
        else:
            values_all.append(replace(ok[0], value=float(np.median([float(v.value) for v in ok]))))
    order = {t.id: i for i, t in enumerate(targets)}
    sim = SimulatedStats(tuple(sorted(values_all, key=lambda v: order[v.target])))
    fit = [t for t in targets if t.role == "fit"]
    dist, z = distance(fit, sim, spec.targets.alpha, sim_se)
    return Evaluation(dict(values), dist, z, sim.to_frame(), time.perf_counter() - t0,
                      float(sum(p[2] for p in parts)), n)


_POOLS: dict[int, Any] = {}


def _pool(workers: int) -> Any:
    """A process pool for the replicate studies of an evaluation (spawned once, reused by every evaluation)."""
    if workers not in _POOLS:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        _POOLS[workers] = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"))
    return _POOLS[workers]


def close_pools() -> None:
    for pool in _POOLS.values():
        pool.shutdown(cancel_futures=True)
    _POOLS.clear()


def dask_client(scheduler: str | None) -> Any:
    if scheduler is None:
        return None
    try:
        from distributed import Client
    except ImportError:
        raise UsageError("--scheduler needs Dask: pip install 'studyctl[power]'") from None
    try:
        return Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise UsageError(f"--scheduler {scheduler}: cannot connect ({exc}); start one with `dask scheduler` "
                         "and workers with `dask worker ADDRESS`") from None
