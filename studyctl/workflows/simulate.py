"""Simulate a study: seeded virtual participants run the protocol through the real engine into a database.

Nothing here computes an outcome. Each virtual participant is enrolled like a person (stratum, sequence
slot, stored schedule), and its session runs through the session engine, the condition's controller,
the simulated device and the scene; the metrics are later computed from what the store recorded.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from studyctl.engine.api import run_session
from studyctl.engine.loop_rates import capped_rates, check_sim_rate
from studyctl.errors import UsageError
from studyctl.populations import SHIPPED, describe_choice
from studyctl.populations import population_for as cohort_population  # re-exported for callers
from studyctl.protocol import load_protocol, resolve_protocol
from studyctl.protocol.schedule import allocate_strata
from studyctl.report.loop_rates import loop_rates_line
from studyctl.store.enrollment import enroll, study_protocol
from studyctl.store.status import study_status
from studyctl.store.workspace import init_workspace, open_study

ProgressFn = Callable[[int, int, str], None]  # (participants done, participants total, message)


def choose_population(protocol: Any, given: Any = None, *, say: Callable[[str], None] | None = None) -> Any:
    """The population a virtual run of ``protocol`` (a loaded protocol) draws its people from, said in one line.

    ``given``: a population file or :class:`~studyctl.populations.TraitPopulation` the user named, or None for the
    protocol's shipped one (None back when it ships none: the participant's own defaults). ``say`` gets the line
    that names it (name, version, sha256 prefix); `studyctl simulate` and `run --rehearse --virtual` both print it.
    """
    population = cohort_population(protocol, SHIPPED if given is None else given)
    if say is not None:
        say(describe_choice(population, protocol.study.id, explicit=given is not None))
    return population


@dataclass(frozen=True)
class SimulationResult:
    """What a simulation produced and how long it took."""

    protocol: str
    study: str
    workspace: str
    database: str
    participants: int
    sessions_completed: int
    trials_completed: int
    trials_not_completed: int
    seed: int
    seconds: float
    population: str = ""  # "name v<version>" of the population used ("" = the participant's defaults)
    population_sha256: str = ""

    COLUMNS = (
        "protocol",
        "study",
        "workspace",
        "database",
        "participants",
        "sessions_completed",
        "trials_completed",
        "trials_not_completed",
        "seed",
        "seconds",
        "population",
        "population_sha256",
    )

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame([asdict(self)], columns=list(self.COLUMNS))


def check_simulation(protocol: str | Path, participants: int, sim_rate_hz: float | None = None, *,
                     out_dir: str | Path | None = None, db: str | None = None) -> Path:
    """The protocol file a simulation would use; raises for an unknown protocol, a bad participant count, a
    bad loop-rate cap, or (when ``out_dir`` is given) a workspace folder or ``--db`` that cannot hold the study."""
    if participants < 1:
        raise UsageError(f"--participants must be at least 1, got {participants}")
    if sim_rate_hz is not None:
        check_sim_rate(sim_rate_hz)
    path = resolve_protocol(protocol)
    if out_dir is not None:
        from studyctl.store.workspace import check_new_workspace

        check_new_workspace(Path(out_dir).expanduser(), db)
    return path


def loop_rates_note(protocol: Any, sim_rate_hz: float) -> str:
    """The loop-rate line ``studyctl power`` prints (:func:`studyctl.report.loop_rates.loop_rates_line`) for a
    simulation of the loaded ``protocol`` capped at ``sim_rate_hz``: the protocol's rates when the cap slows none of
    its loops (a study with no rate-adjustable loop faster than it), so such a run is not silently taken for a
    capped one."""
    rates, cap = capped_rates(protocol, sim_rate_hz)
    return loop_rates_line(rates, cap, undo="leave --sim-rate-hz out")


@dataclass(frozen=True)
class Cohort:
    """A new study workspace with its enrolled (not yet run) virtual participants."""

    protocol: str
    study: str
    workspace: str
    database: str
    codes: tuple[str, ...]
    seed: int
    db: str | None = None
    sim_rate_hz: float | None = None  # loop-rate cap of the sessions (see run_session); None: protocol rates
    population: Any = None  # TraitPopulation each virtual person is drawn from; None: the participant's defaults


def create_cohort(
    protocol: str | Path,
    participants: int,
    seed: int,
    out_dir: str | Path,
    *,
    db: str | None = None,
    sim_rate_hz: float | None = None,
    population: Any = SHIPPED,
) -> Cohort:
    """Create the workspace and enroll ``participants``, spread over the strata by their target sizes.

    Enrollment stores each participant's schedule (sequence slot, placements) exactly as for people.
    ``sim_rate_hz`` caps the loop rate of the cohort's sessions (:func:`studyctl.engine.api.run_session`).
    ``population``: a :class:`~studyctl.populations.TraitPopulation` or a population file; the default
    (:data:`SHIPPED`) is the protocol's shipped population when there is one; None: the participant's defaults.
    """
    # the population is checked before anything is written: a bad file leaves no half-made workspace
    loaded = load_protocol(check_simulation(protocol, participants, sim_rate_hz))  # read once, stored as read
    population = cohort_population(loaded, population)
    init = init_workspace(out_dir, protocol=loaded, seed=int(seed), db=db)
    with open_study(db, str(init.root), init.study) as opened:
        proto = study_protocol(opened.study)
        several = len(proto.participants.strata) > 1
        # Virtual participants get numbered codes (a person gets a random one): the session seed derives from
        # the study seed and the code, so the same seed reproduces the same sessions and the same data.
        prefix = proto.participants.code_prefix
        codes = tuple(
            enroll(opened.store, stratum if several else None, study=opened.study.name, code=f"{prefix}-V{i:03d}",
                   over_target=True).code
            for i, (stratum, _) in enumerate(allocate_strata(proto, participants), start=1)
        )
        name = opened.study.name
    return Cohort(str(protocol), name, str(init.root), str(init.database), codes, int(seed), db, sim_rate_hz,
                  population)


def run_participant(cohort: Cohort, code: str, *, durable: bool = False, store=None) -> str:  # noqa: ANN001
    """Run one enrolled virtual participant's whole session through the engine; returns its status.

    Safe to call from several processes at once for different participants of the same SQLite study:
    each commit is a short transaction and SQLite serialises writers (busy timeout).
    """
    def run(target) -> str:  # noqa: ANN001
        result = run_session(target, code, study=cohort.study, virtual=True, sim_rate_hz=cohort.sim_rate_hz,
                             population=cohort.population)
        return str(getattr(result, "status", ""))

    if store is not None:
        return run(store)
    with open_study(cohort.db, cohort.workspace, cohort.study) as opened:
        if not durable:
            relax_sqlite_durability(opened.store)
        return run(opened.store)


def summarize(cohort: Cohort, *, sessions_completed: int, seconds: float) -> SimulationResult:
    """Trial counts of a simulated cohort, read back from its database."""
    with open_study(cohort.db, cohort.workspace, cohort.study) as opened:
        counts = study_status(opened.store, opened.study).trials
    return SimulationResult(
        protocol=cohort.protocol,
        study=cohort.study,
        workspace=cohort.workspace,
        database=cohort.database,
        participants=len(cohort.codes),
        sessions_completed=sessions_completed,
        trials_completed=counts.get("completed", 0),
        trials_not_completed=sum(v for k, v in counts.items() if k != "completed"),
        seed=cohort.seed,
        seconds=seconds,
        population="" if cohort.population is None else f"{cohort.population.name} v{cohort.population.version}",
        population_sha256="" if cohort.population is None else cohort.population.sha256,
    )


def simulate_study(
    protocol: str | Path,
    participants: int,
    seed: int,
    out_dir: str | Path,
    *,
    db: str | None = None,
    durable: bool = False,
    sim_rate_hz: float | None = None,
    on_progress: ProgressFn | None = None,
    population: Any = SHIPPED,
) -> SimulationResult:
    """Create a study workspace in ``out_dir`` and run ``participants`` virtual participants through it.

    Parameters
    ----------
    protocol
        A shipped protocol name or a protocol file.
    participants
        How many to enroll; they are spread over the strata in proportion to their target sizes.
    seed
        The study's master seed: schedules, placements and every participant's behaviour follow from it.
    out_dir
        A new or empty folder for the workspace (``studyctl.toml`` and ``study.db``).
    db
        A PostgreSQL URL to hold the study instead of ``study.db``.
    durable
        Keep the store's full power-loss durability (an fsync at every commit). By default a simulated
        study's SQLite database runs with ``synchronous = NORMAL`` in WAL mode: still safe against a crashed
        process and never corrupted, but the last commits may be lost on power loss, which costs nothing
        here because the study is regenerated from its seed. On this project's 2-core VM the fsyncs
        otherwise took about two thirds of the wall time of a seed 000 simulation.
    sim_rate_hz
        Run the feedback loop of rate-adjustable controllers at most this fast (None: the protocol's rates,
        1 kHz for the tissue and needle controllers); ``studyctl bench simrate`` measures what it changes.
    on_progress
        Called after each participant with (done, total, message).
    population
        Where the virtual people come from: the protocol's shipped population (default, when one exists), a
        population file or :class:`~studyctl.populations.TraitPopulation`, or None for the participant's
        own defaults. Each session stores the population's sha256 and the person's traits.
    """
    t0 = time.perf_counter()
    cohort = create_cohort(protocol, participants, seed, out_dir, db=db, sim_rate_hz=sim_rate_hz,
                           population=population)
    sessions = 0
    with open_study(db, cohort.workspace, cohort.study) as opened:
        if not durable:
            relax_sqlite_durability(opened.store)
        for i, code in enumerate(cohort.codes):
            if run_participant(cohort, code, store=opened.store) == "completed":
                sessions += 1
            if on_progress is not None:
                on_progress(i + 1, len(cohort.codes), code)
    return summarize(cohort, sessions_completed=sessions, seconds=time.perf_counter() - t0)


def relax_sqlite_durability(store) -> bool:  # noqa: ANN001
    """Make this store's SQLite connections commit without waiting for the disk (WAL, synchronous=NORMAL).

    Applies to connections opened from now on (the pool is emptied). No effect on PostgreSQL. Returns
    whether the setting was applied.
    """
    from sqlalchemy import event

    engine = store.db.engine
    if engine.dialect.name != "sqlite":
        return False

    def _normal_sync(dbapi_connection, _record) -> None:  # noqa: ANN001 - runs after the store's own hook
        cur = dbapi_connection.cursor()
        try:
            cur.execute("PRAGMA synchronous = NORMAL")
        finally:
            cur.close()

    event.listen(engine, "connect", _normal_sync)
    engine.dispose()
    return True

