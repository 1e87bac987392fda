"""One replicate study: enroll N virtual participants into a throwaway in-memory database, run each one's
whole session through the real engine, compute the plan's metrics from what the store recorded, and run
the plan. Nothing here computes an outcome; the tests' rows are what the analysis runner returned.

:func:`simulate_replicate` is the unit of work a Dask worker runs; it depends only on its arguments.
"""

from __future__ import annotations

import math
import os
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import pandas as pd

from studyctl.analysis import compute_metrics
from studyctl.analysis.execute import hypothesis_rows
from studyctl.analysis.results import TestRow
from studyctl.analysis.shape import prepare
from studyctl.engine.api import run_session
from studyctl.engine.factory import EntryPointFactory
from studyctl.engine.seeding import person_traits
from studyctl.errors import SessionInterrupted, StudyctlError
from studyctl.power.population import population_model
from studyctl.power.seeds import replicate_seeds
from studyctl.power.spec import TEST_KINDS, PowerSpec
from studyctl.protocol import allocate_strata, load_protocol_text
from studyctl.store import StudyStore
from studyctl.store.enrollment import enroll
from studyctl.store.status import study_status

#: Columns of :meth:`ReplicateResult.to_frame` (one row per hypothesis-test row of the plan's result).
ROW_COLUMNS = (
    "participants",
    "replicate",
    "test_id",
    "role",
    "kind",
    "test",
    "metric",
    "split",
    "groups",
    "parent",
    "p",
    "p_adj",
    "significant",
    "effect_size_name",
    "effect_size",
    "status",
)
_KEEP = ROW_COLUMNS[2:]


class WorkerMemoryError(StudyctlError, MemoryError):
    """A replicate went over the per-worker memory cap."""


@dataclass(frozen=True)
class ReplicateResult:
    """The tests of one replicate study and what it took.

    ``rows`` are tuples in :data:`ROW_COLUMNS` order without the first two (sample size, replicate);
    ``clipped`` counts participant parameters the population's spread pushed past their range;
    ``seconds`` is wall time and ``cpu_seconds`` the CPU time of the process that ran it (with other
    threads of that process); ``worker`` is ``host:pid`` of that process (for the record; results never
    depend on it).
    """

    participants: int
    replicate: int
    rows: tuple[tuple[Any, ...], ...]
    sessions_completed: int
    trials_completed: int
    trials_not_completed: int
    clipped: int
    seconds: float
    cpu_seconds: float
    peak_rss_mb: float
    worker: str

    def to_frame(self) -> pd.DataFrame:
        data = [(self.participants, self.replicate, *row) for row in self.rows]
        return pd.DataFrame(data, columns=list(ROW_COLUMNS))


def _rss_bytes() -> int | None:
    """This process's resident memory now (Linux /proc; psutil elsewhere when installed)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        pass
    try:
        import psutil
    except ImportError:
        return None
    return int(psutil.Process().memory_info().rss)


def _check_memory(limit: int | None, where: str) -> float:
    rss = _rss_bytes()
    if limit is not None and rss is not None and rss > limit:
        raise WorkerMemoryError(
            f"{where}: the worker uses {rss / 2**20:.0f} MiB, over the cap of "
            f"{limit / 2**20:.0f} MiB per worker; raise --memory-limit or use fewer participants"
        )
    return math.nan if rss is None else rss / 2**20


_FLOATS = frozenset({"p", "p_adj", "effect_size"})
#: text fields a missing value of becomes ""
_TEXT = frozenset({"parent", "effect_size_name", "split", "groups", "metric", "role", "test"})


def _missing(v: object) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def power_rows(rows: tuple[TestRow, ...]) -> tuple[tuple, ...]:
    """The power rows (:data:`ROW_COLUMNS` without size and index) of a replicate's test rows, read straight from
    the rows: NaN for a missing number, "" for missing text, significance as bool or None. Full-engine and stage-2
    replicates both call it; a stage-2 run makes ~100 rows thousands of times, so no DataFrame is built
    (tests/power check it against the rows frame's values)."""
    out = []
    for r in rows:
        if r.kind not in TEST_KINDS:
            continue
        row = []
        for name in _KEEP:
            v = getattr(r, name)
            if hasattr(v, "item"):
                v = v.item()
            if name in _FLOATS:
                v = math.nan if v is None else float(v)
            elif name == "significant":
                v = None if _missing(v) else bool(v)
            elif name in _TEXT:
                v = "" if _missing(v) else str(v)
            row.append(v)
        out.append(tuple(row))
    return tuple(out)


def participant_code(prefix: str, index: int) -> str:
    """The code of the ``index``-th (0-based) participant of a replicate (codes never feed randomness)."""
    return f"{prefix}-V{index + 1:04d}"


@dataclass(frozen=True)
class StudyOutcome:
    """One simulated study: its metric table and, per enrolled person, (code, stratum, sequence index)."""

    table: Any  # MetricTable
    members: tuple[tuple[str, str, int | None], ...]
    completed: int
    clipped: int
    trials: dict[str, int]
    peak_rss_mb: float


def simulate_study(spec: PowerSpec, participants: int, seeds: Any, name: str, where: str) -> StudyOutcome:
    """Enroll ``participants`` virtual people into a throwaway in-memory study and run each one's whole session
    through the real engine (see :func:`simulate_replicate`); return the metrics the plan computes from it."""
    protocol = load_protocol_text(spec.protocol_text, f"{spec.protocol_name} (power spec)")
    factory = EntryPointFactory()
    model = population_model(spec.population, protocol, factory)
    offsets_rng = seeds.population_rng()
    pairs = allocate_strata(protocol, participants)
    several = len(protocol.stratum_ids) > 1
    prefix = protocol.participants.code_prefix
    completed = clipped = 0
    members = []
    peak = _check_memory(spec.memory_limit, where)
    store = StudyStore.create("sqlite://")
    try:
        study = store.create_study(name, protocol_text=spec.protocol_text, protocol_name=spec.protocol_name,
                                   seed=seeds.study_seed)
        for i, (stratum, _slot) in enumerate(pairs):
            enrolled = enroll(store, stratum if several else None, study=study.name, code=participant_code(prefix, i),
                              over_target=True)
            members.append((enrolled.code, enrolled.stratum, enrolled.sequence))
            traits = None
            if spec.traits is not None:  # this person's traits, then the knobs' shifts on top
                traits = person_traits(spec.traits, seeds.session_seeds[i], enrolled.stratum)
            actor, n_clipped = model.actor(enrolled.stratum, model.draw_offsets(offsets_rng),
                                           None if traits is None else spec.traits.params(traits))
            clipped += n_clipped
            try:
                result = run_session(store, enrolled.code, study=study.name, virtual=True,
                                     seed=seeds.session_seeds[i], participant=actor, factory=factory,
                                     population=spec.traits, traits=traits, sim_rate_hz=spec.sim_rate_hz)
            except SessionInterrupted:
                # Ctrl-C inside a session: the engine made it resumable, but this study lives in memory and is
                # dropped; the replicate simply did not finish (a rerun of the power command redoes it).
                raise KeyboardInterrupt from None
            completed += getattr(result, "status", "") == "completed"
            peak = max(peak, _check_memory(spec.memory_limit, where))
        table = compute_metrics(spec.plan, store, study)
        trials = dict(study_status(store, study).trials)
    finally:
        store.close()
    return StudyOutcome(table, tuple(members), int(completed), int(clipped), trials, peak)


def simulate_replicate(
    spec: PowerSpec, participants: int, replicate: int, *, on_metrics: Callable[[Any], None] | None = None
) -> ReplicateResult:
    """Simulate replicate ``replicate`` of a study with ``participants`` virtual participants.

    The study lives in an in-memory SQLite database that is dropped afterwards; enrollment, sessions
    (simulated clock, the protocol's controllers, devices and scene) and the metrics are the same code
    paths a real study uses. Participants are enrolled stratum by stratum in proportion to the strata's
    target sizes (:func:`studyctl.protocol.allocate_strata`), each with the population's parameters.

    ``on_metrics`` (optional) is handed the replicate's :class:`~studyctl.analysis.MetricTable` before the
    plan runs (to look at the simulated data; the result does not depend on it).

    Returns
    -------
    ReplicateResult
        One row per hypothesis test of the plan (omnibus, two-sample, pairwise and post-hoc rows).
    """
    t0, c0 = time.perf_counter(), time.process_time()
    where = f"replicate {replicate} at {participants} participants"
    seeds = replicate_seeds(spec.seed, participants, replicate)
    study = simulate_study(spec, participants, seeds, f"{spec.study_id}-power-n{participants}-r{replicate}", where)
    if on_metrics is not None:
        on_metrics(study.table)
    # the plan's hypothesis tests only (what power counts; descriptive tables and intervals are not run)
    rows = power_rows(hypothesis_rows(spec.plan, prepare(spec.plan, study.table)))
    trials, completed, clipped, peak = study.trials, study.completed, study.clipped, study.peak_rss_mb
    return ReplicateResult(
        participants=int(participants),
        replicate=int(replicate),
        rows=rows,
        sessions_completed=int(completed),
        trials_completed=trials.get("completed", 0),
        trials_not_completed=sum(v for k, v in trials.items() if k != "completed"),
        clipped=int(clipped),
        seconds=time.perf_counter() - t0,
        cpu_seconds=time.process_time() - c0,
        peak_rss_mb=peak,
        worker=f"{socket.gethostname()}:{os.getpid()}",
    )

