"""A two-stage power analysis: build (or reuse) the pool, draw replicate studies from it, check against full-engine
replicates at a few sizes, summarise and write the same report folder as a full-engine run."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from pathlib import Path

from studyctl.errors import UsageError
from studyctl.power.bootstrap import pool_bootstrap
from studyctl.power.executor import SerialBackend, open_backend
from studyctl.power.pool import build_pool, check_pool_size
from studyctl.power.population import population_model
from studyctl.power.replicate import ReplicateResult
from studyctl.power.results import ResultsFile
from studyctl.power.spec import PowerSpec
from studyctl.power.summary import summarise
from studyctl.power.target import smallest_sizes
from studyctl.power.twostage import PowerError, Stage2, batches, compare, draw_batch
from studyctl.workflows.power import PowerRun, _atomic, _write, run_power

ERROR_FILE = "power_error.csv"
POOL_ERROR_FILE = "power_pool_error.csv"
#: Stage-2 replicates per Dask task at most (a replicate takes ~0.1–1 s: tens per task keep scheduling small).
STAGE2_BATCH = 50
STAGE2_DIR = "two_stage"
EXACT_DIR = "exact_check"


def check_sizes_of(spec: PowerSpec, check: str | tuple[int, ...] | None) -> tuple[int, ...]:
    """The sizes the two-stage error is measured at: a subset of the run's sizes (default: the smallest)."""
    from studyctl.power.spec import parse_sizes

    if check is None:
        return (spec.sizes[0],)
    sizes = parse_sizes(check)
    extra = [n for n in sizes if n not in spec.sizes]
    if extra:
        raise UsageError(f"--check-sizes {', '.join(map(str, extra))}: not among --participants "
                         f"{', '.join(map(str, spec.sizes))}; check a subset of the sizes run")
    return sizes


def run_two_stage(
    spec: PowerSpec,
    out_dir: str | Path,
    *,
    pool_dir: str | Path,
    pool: int | None = None,
    check_sizes: tuple[int, ...] | None = None,
    check_replicates: int = 50,
    boot_pools: int = 20,
    boot_replicates: int = 50,
    scheduler: str | None = None,
    workers: int | None = None,
    on_stage: Callable[[str, int, int], None] | None = None,
    figure: bool = True,
) -> PowerRun:
    """Stage 1 (pool of ``pool`` people, default 20 × the largest n, in ``pool_dir``), stage 2 (every replicate
    of ``spec`` drawn from it), and ``check_replicates`` full-engine replicates at ``check_sizes`` (0: no check)
    compared with it, the pool's own error measured at those sizes by ``boot_pools`` bootstrap pools of
    ``boot_replicates`` stage-2 replicates each (:mod:`studyctl.power.bootstrap`; 0 pools: not measured).

    ``on_stage(stage, done, total)`` reports progress ("pool", "stage 2", "exact check").
    """
    t0 = time.perf_counter()
    out = Path(out_dir).expanduser()
    people = check_pool_size(pool, spec.sizes)
    checks = tuple(check_sizes or ())
    if check_replicates < 0:
        raise UsageError(f"--check-replicates must be 0 or more, got {check_replicates}")
    if boot_pools < 0 or boot_pools == 1 or boot_replicates < 2:
        raise UsageError(f"--pool-bootstrap {boot_pools} with {boot_replicates} replicates each: the pool's error "
                         "needs 0 (not measured) or at least 2 bootstrap pools of at least 2 replicates; use e.g. "
                         "--pool-bootstrap 20")
    backend = open_backend(scheduler, workers, spec.memory_limit)
    try:
        backend_desc = backend.info.describe()
        p0 = time.perf_counter()
        built = build_pool(spec, pool_dir, people, backend,
                           on_chunk=None if on_stage is None else lambda d, t: on_stage("pool", d, t))
        pool_wall = time.perf_counter() - p0
        fp = {**spec.fingerprint(), "design": "two-stage", "pool": built.path.name, "pool_people": built.size}
        tasks = spec.tasks()
        s0 = time.perf_counter()
        stage2_cpu = 0.0
        with ResultsFile.open(out / STAGE2_DIR, fp) as results:
            done = results.done()
            todo = [t for t in tasks if t not in done]
            count = [len(tasks) - len(todo)]

            def keep(result: ReplicateResult | list[ReplicateResult]) -> None:
                nonlocal stage2_cpu
                for one in result if isinstance(result, list) else [result]:
                    results.add(one)
                    stage2_cpu += one.cpu_seconds
                    count[0] += 1
                    if on_stage is not None:
                        on_stage("stage 2", count[0], len(tasks))

            if isinstance(backend, SerialBackend):
                stage2 = Stage2(spec, built)
                for n, r in todo:
                    keep(stage2.replicate(n, r))
            else:  # batches of replicates on the workers, each loading the pool file once
                per_task = max(1, min(STAGE2_BATCH, math.ceil(len(todo) / (4 * max(backend.info.workers, 1)))))
                backend.map(draw_batch, spec, [(str(built.path), math.ceil(built.size / built.chunk_size),
                                                built.chunk_size, n, a, b) for n, a, b in batches(todo, per_task)],
                            keep, tag="stage2")
            rows, reps = results.rows(tasks), results.replicates(tasks)
        stage2_wall = time.perf_counter() - s0
    except KeyboardInterrupt:
        backend.abort()
        raise
    finally:
        backend.close()
    per_size = {n: int((reps["participants"] == n).sum()) for n in spec.sizes}
    table = summarise(rows, spec.sizes, per_size)
    error = boot = None
    if checks and boot_pools:
        if on_stage is not None:
            on_stage("pool bootstrap", 0, len(checks))
        boot = pool_bootstrap(spec, built, checks, boot_pools, boot_replicates)
        if on_stage is not None:
            on_stage("pool bootstrap", len(checks), len(checks))
    if checks and check_replicates:
        exact_spec = dataclasses.replace(spec, sizes=checks, replicates=check_replicates, target=None)
        exact = run_power(exact_spec, out / EXACT_DIR, scheduler=scheduler, workers=workers, figure=False,
                          on_progress=None if on_stage is None else
                          lambda d, t, _r: on_stage("exact check", d, t))
        error = compare(table.frame, exact.table.frame, checks, None if boot is None else boot.to_frame())
    target = None if spec.target is None else smallest_sizes(table.frame, spec.target)
    population = population_model(spec.population, spec.load_protocol()).to_frame()
    note = _note(error, built.size)
    files = _write(out, spec, table, population, reps, f"two-stage: pool and stage 2 on {backend_desc}",
                   figure, target, note=note)
    if boot is not None:
        files["pool_error"] = out / POOL_ERROR_FILE
        _atomic(files["pool_error"], lambda p: boot.to_frame().to_csv(p, index=False))
    if error is not None:
        files["error"] = out / ERROR_FILE
        _atomic(files["error"], lambda p: error.to_frame().to_csv(p, index=False))
    pool_info = {
        "path": str(built.path), "people": built.size, "chunk_size": built.chunk_size,
        "chunks_built_now": built.built_now, "build_seconds_this_run": pool_wall,
        "build_worker_seconds_total": built.build_seconds, "build_cpu_seconds_total": built.build_cpu_seconds,
        "stage2_seconds": stage2_wall, "stage2_cpu_seconds": stage2_cpu, "stage2_replicates_run": len(todo),
        "stage2_replicates_per_s": (len(todo) / stage2_wall) if todo and stage2_wall > 0 else None,
    }
    _atomic(out / "power_two_stage.json", lambda p: p.write_text(json.dumps(
        {"pool": pool_info, "error": None if error is None else error.summary()}, indent=2, default=str),
        encoding="utf-8"))
    return PowerRun(table=table, out_dir=out, files=files, ran=len(todo), reused=len(tasks) - len(todo),
                    seconds=time.perf_counter() - t0, backend=f"two-stage (pool and stage 2: {backend_desc})",
                    population=population, replicates=reps, target=target, error=error, pool=pool_info,
                    sim_rate_hz=spec.sim_rate_hz, loop_rates_hz=spec.loop_rates())


def _note(error: PowerError | None, people: int) -> str:
    if error is None:
        return f"two-stage design: {people}-person pool; error against full-engine replicates not checked"
    e = error.summary()
    pool = ("pool SE not measured" if not math.isfinite(e["pool_se_pp_max"])
            else f"pool SE up to {e['pool_se_pp_max']:.1f} pp")
    return (f"two-stage design ({people}-person pool): max |two-stage - full engine| = {e['power_error_pp']:.1f} pp "
            f"± {e['power_error_se_pp']:.1f} (SE) at n = {', '.join(map(str, error.sizes))} "
            f"({error.exact_replicates} full-engine replicates; MC SE up to {e['mc_se_exact_pp_max']:.1f} pp full "
            f"engine, {e['mc_se_two_stage_pp_max']:.1f} pp stage 2; {pool}; chi2 {e['chi2']:.0f} on {e['rows']} rows)")
