"""A whole power analysis: check, run the missing replicates somewhere, summarise, write the report folder."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from studyctl.power.executor import open_backend
from studyctl.power.population import population_model
from studyctl.power.replicate import ReplicateResult
from studyctl.power.results import ResultsFile
from studyctl.power.spec import PowerSpec
from studyctl.power.summary import PowerTable, summarise
from studyctl.power.target import TargetTable, smallest_sizes
from studyctl.report.loop_rates import loop_rates_line
from studyctl.report.power_figures import power_curve_figure, write_png

ProgressFn = Callable[[int, int, ReplicateResult | None], None]  # (finished, total, the replicate just finished)

TABLE_FILE = "power.csv"
FIGURE_FILE = "power_curve.png"
POPULATION_FILE = "power_population.csv"
REPLICATES_FILE = "power_replicates.csv"
SETTINGS_FILE = "power_run.json"
TARGET_FILE = "power_target.csv"


@dataclass(frozen=True)
class PowerRun:
    """The outcome of :func:`run_power`: the power table and what was written where.

    ``ran`` replicates were simulated by this call and ``reused`` came from the results file of an
    earlier (interrupted or smaller) run with the same settings.
    """

    table: PowerTable
    out_dir: Path
    files: dict[str, Path]
    ran: int
    reused: int
    seconds: float
    backend: str
    population: pd.DataFrame = field(repr=False)
    replicates: pd.DataFrame = field(repr=False)
    #: Per test, the smallest size run reaching ``spec.target`` (None without a target).
    target: TargetTable | None = None
    #: Two-stage runs: the design's measured error against full-engine replicates, and the pool used.
    error: Any = None
    pool: dict[str, Any] | None = None
    #: The simulated sessions' loop-rate cap (``--sim-rate-hz``; None: the protocol's rates) and the rate each
    #: condition with a controller ran at.
    sim_rate_hz: float | None = None
    loop_rates_hz: dict[str, float] = field(default_factory=dict)

    def to_frame(self) -> pd.DataFrame:
        """The power table (:data:`studyctl.power.summary.COLUMNS`)."""
        return self.table.to_frame()


def run_power(
    spec: PowerSpec,
    out_dir: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    on_progress: ProgressFn | None = None,
    on_backend: Callable[[str], None] | None = None,
    figure: bool = True,
) -> PowerRun:
    """Simulate every replicate of ``spec`` not yet in ``out_dir``, then summarise and write the report.

    Parameters
    ----------
    spec
        From :func:`studyctl.power.prepare_power` (everything is checked there).
    out_dir
        The report folder: ``power.csv`` (the table), ``power_curve.png``, ``power_population.csv``
        (the stated population), ``power_replicates.csv``, ``power_run.json`` and the results file
        ``power_results.sqlite`` that makes runs resumable.
    scheduler
        Address of an existing Dask scheduler (``tcp://host:8786``); None starts a local cluster.
    workers
        Local cluster: worker processes (default: one per core); ``0``: serial in this process. With
        ``scheduler``: how many workers to wait for (default 1).
    on_progress
        Called with (finished, total, replicate) after each replicate, and once at the start with the
        replicates already in the results file (replicate None).
    on_backend
        Called with a description of where the replicates run, once connected.

    Returns
    -------
    PowerRun
        Identical for any ``workers``/``scheduler`` (each replicate depends only on the seed and its
        (sample size, replicate index)).
    """
    t0 = time.perf_counter()
    out = Path(out_dir).expanduser()
    tasks = spec.tasks()
    # Connect before writing anything: an unreachable scheduler leaves no trace in the report folder.
    todo = [t for t in tasks if t not in ResultsFile.finished(out, spec.fingerprint())]
    backend = open_backend(scheduler, workers, spec.memory_limit) if todo else None
    backend_desc = "none (every replicate was already in the results file)"
    try:
        with ResultsFile.open(out, spec.fingerprint()) as results:
            done = results.done()
            todo = [t for t in tasks if t not in done]
            finished = len(tasks) - len(todo)
            if on_progress is not None:
                on_progress(finished, len(tasks), None)
            if backend is not None and todo:
                backend_desc = backend.info.describe()
                if on_backend is not None:
                    on_backend(backend_desc)
                count = [finished]

                def keep(result: ReplicateResult) -> None:
                    results.add(result)
                    count[0] += 1
                    if on_progress is not None:
                        on_progress(count[0], len(tasks), result)

                backend.run(spec, todo, keep)
            rows = results.rows(tasks)
            reps = results.replicates(tasks)
    except KeyboardInterrupt:
        if backend is not None:
            backend.abort()
        raise
    finally:
        if backend is not None:
            backend.close()
    per_size = {n: int((reps["participants"] == n).sum()) for n in spec.sizes}
    table = summarise(rows, spec.sizes, per_size)
    target = None if spec.target is None else smallest_sizes(table.frame, spec.target)

    population = population_model(spec.population, spec.load_protocol()).to_frame()
    files = _write(out, spec, table, population, reps, backend_desc, figure, target)
    return PowerRun(
        table=table,
        out_dir=out,
        files=files,
        ran=len(todo),
        reused=finished,
        seconds=time.perf_counter() - t0,
        backend=backend_desc,
        population=population,
        replicates=reps,
        target=target,
        sim_rate_hz=spec.sim_rate_hz,
        loop_rates_hz=spec.loop_rates(),
    )


def rates_note(spec: PowerSpec) -> str | None:
    """The figure's line on a capped loop rate (it is what gets shown and published; the words the run printed);
    None at the protocol's rates."""
    if spec.sim_rate_hz is None:
        return None
    return loop_rates_line(spec.loop_rates(), spec.sim_rate_hz)


def _atomic(path: Path, write: Callable[[Path], Any]) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _write(
    out: Path,
    spec: PowerSpec,
    table: PowerTable,
    population: pd.DataFrame,
    reps: pd.DataFrame,
    backend: str,
    figure: bool,
    target: TargetTable | None = None,
    note: str | None = None,
) -> dict[str, Path]:
    files = {
        "table": out / TABLE_FILE,
        "population": out / POPULATION_FILE,
        "replicates": out / REPLICATES_FILE,
        "settings": out / SETTINGS_FILE,
        "results": out / "power_results.sqlite",
    }
    _atomic(files["table"], lambda p: table.to_frame().to_csv(p, index=False))
    _atomic(files["population"], lambda p: population.to_csv(p, index=False))
    _atomic(files["replicates"], lambda p: reps.to_csv(p, index=False))
    if target is not None:
        files["target"] = out / TARGET_FILE
        _atomic(files["target"], lambda p: target.to_frame().to_csv(p, index=False))
    settings = {
        "protocol": spec.protocol_name,
        "study": spec.study_id,
        "plan": spec.plan.source_path,
        "plan_title": spec.plan.title,
        "alpha": spec.plan.alpha,
        "participants": list(spec.sizes),
        "replicates": spec.replicates,
        "target": spec.target,
        "seed": spec.seed,
        "population": spec.population.to_dict(),
        "memory_limit_bytes": spec.memory_limit,
        "sim_rate_hz": spec.sim_rate_hz,
        "loop_rates_hz": spec.loop_rates(),
        "backend": backend,
        **{"fingerprint": spec.fingerprint()},
        "seeds": "numpy SeedSequence(seed, spawn_key=(participants, replicate))",
    }
    _atomic(files["settings"], lambda p: p.write_text(json.dumps(settings, indent=2, default=str), encoding="utf-8"))
    if figure and not table.frame.empty:
        note = "\n".join(filter(None, [note, rates_note(spec)]))
        fig = power_curve_figure(
            table.to_frame(),
            title=f"Power by sample size: {spec.plan.title}",
            alpha=spec.plan.alpha,
            replicates=spec.replicates,
            population=spec.population,
            target=None if target is None else target.to_frame(),
            target_power=spec.target,
            note=note,
        )
        files["figure"] = out / FIGURE_FILE
        _atomic(files["figure"], lambda p: write_png(fig, p))
    return files
