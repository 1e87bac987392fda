"""The inputs of ``studyctl calibrate``, checked before any simulation: the protocol and its plan, the targets,
the starting population and its free parameters, the sizes and the seed (:func:`prepare_calibration`)."""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from studyctl.errors import PopulationError, UsageError

SIGMA0 = 0.25  # CMA-ES initial step, as a fraction of each free parameter's search range
SAMPLER = f"cmaes(x0=population, sigma0={SIGMA0})"  # part of the journal's fingerprint
DEFAULT_EVALUATIONS = 24
DEFAULT_FIT_PARTICIPANTS = 4  # people per simulated study of an evaluation
DEFAULT_REPLICATES = 2  # simulated studies per evaluation (run in parallel on the local workers)
DEFAULT_SIM_RATE_HZ = 250.0  # as `studyctl demo`: the 1 kHz tissue and needle loops at 250 Hz


@dataclass(frozen=True)
class CalibrationSpec:
    """Everything a calibration needs, checked before any simulation (see :func:`prepare_calibration`)."""

    protocol_id: str
    protocol_text: str
    plan: Any
    population: Any  # TraitPopulation (the starting values)
    targets: Any  # TargetSet
    free: tuple[Any, ...]  # FreeParam
    seed: int
    participants: int
    paper_participants: int
    replicates: int
    evaluations: int
    out: Path
    scheduler: str | None = None
    workers: int = 1  # local worker processes for the replicate studies of an evaluation (no scheduler)
    sim_rate_hz: float | None = None  # loop-rate cap of rate-adjustable controllers (as the demo's)

    @property
    def fit_targets(self) -> tuple[Any, ...]:
        return self.targets.by_role("fit")

    def setup(self) -> dict[str, Any]:
        """What was fitted, to which targets, with how many simulated people: the part of a fit that both the
        population file's calibration block and the fit report state."""
        return {
            "free": [f.name for f in self.free],
            "used_for_fit": [t.id for t in self.fit_targets],
            "validation": [t.id for t in self.targets.by_role("validation")],
            "seed": self.seed,
            "participants": self.participants,
            "replicates": self.replicates,
        }

    def fingerprint(self) -> str:
        """What the journal's evaluations depend on (another setting starts a new journal study)."""
        from studyctl import __version__

        data = {
            "studyctl": __version__, "protocol": hashlib.sha256(self.protocol_text.encode()).hexdigest(),
            "population": self.population.sha256, "targets": self.targets.sha256,
            "free": [(f.name, f.low, f.high) for f in self.free], "seed": self.seed,
            "participants": self.participants, "replicates": self.replicates, "sim_rate_hz": self.sim_rate_hz,
            "sampler": SAMPLER,
        }
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]

    @property
    def journal(self) -> Path:
        return self.out.with_name(self.out.name + ".journal")


def prepare_calibration(
    protocol: str | Path,
    targets: str | Path | None,
    *,
    population: str | Path | None = None,
    free: Sequence[str] | str | None = None,
    seed: int = 1,
    participants: int | None = None,
    replicates: int = DEFAULT_REPLICATES,
    evaluations: int = DEFAULT_EVALUATIONS,
    out: str | Path | None = None,
    scheduler: str | None = None,
    pilot_db: str | None = None,
    workers: int | None = None,
    sim_rate_hz: float | None = DEFAULT_SIM_RATE_HZ,
) -> CalibrationSpec:
    """Check every input (protocol, plan, population, targets, free parameters, sizes) before any work.

    Raises
    ------
    PopulationError, UsageError, NotFoundError
        One line naming what is wrong and how to fix it.
    """
    from studyctl.analysis import load_plan
    from studyctl.populations import free_params
    from studyctl.populations.loader import participant_params
    from studyctl.populations.targets import load_targets_file
    from studyctl.protocol import load_protocol, resolve_protocol

    path = resolve_protocol(protocol)
    proto = load_protocol(path)
    pid = proto.study.id
    # the files read (protocol, targets, plan) before the simulation stack is imported (choose_population and the
    # master seed check bring in the engine, the store and pandas): a hostile file is refused by a small process
    if targets is None and pilot_db is None:
        from studyctl.populations.targets import shipped_targets_path

        targets = shipped_targets_path(pid)
        if targets is None:
            raise UsageError(f"no targets: give --targets FILE (or --pilot-db DB); protocol {pid!r} ships none")
    plan = load_plan(_plan_ref(targets, pid))
    if pilot_db is not None:
        from studyctl.calibration.pilot import pilot_targets

        tset = pilot_targets(pilot_db, plan, proto, template=targets)
    else:
        tset = load_targets_file(targets, plan=plan, protocol=proto)
    if tset.protocol != pid:
        raise PopulationError(f"targets {tset.path} are for protocol {tset.protocol!r}, not {pid!r}")
    if not tset.by_role("fit"):
        raise PopulationError(f"targets {tset.path} have no role: fit target; calibrate fits only on fit targets")
    from studyctl.power.seeds import check_master_seed
    from studyctl.workflows.simulate import choose_population

    pop = choose_population(proto, population)
    if pop is None:
        raise PopulationError(f"protocol {pid!r} has no shipped population to start from; give one with "
                              "--population FILE (format: studyctl-population/1)")
    names = free if free is not None else list(pop.calibration.get("free") or [])
    if isinstance(names, str):
        names = [n for n in names.split(",") if n.strip()]
    from studyctl.plugins.registry import load_plugin

    declared = participant_params(load_plugin("participant", pop.participant))
    fps = free_params(pop, list(names), declared=declared, strata=list(proto.stratum_ids))
    if participants is None:
        participants = DEFAULT_FIT_PARTICIPANTS
    strata = max(len(proto.stratum_ids), 1)
    if isinstance(participants, bool) or not isinstance(participants, int) or participants < max(2, strata):
        raise UsageError(f"--participants must be a whole number ≥ {max(2, strata)} (people per simulated study "
                         f"in each evaluation), got {participants!r}")
    if not isinstance(replicates, int) or not 1 <= replicates <= 100:
        raise UsageError(f"--replicates must be 1..100, got {replicates!r}")
    if not isinstance(evaluations, int) or not len(fps) + 1 <= evaluations <= 10000:
        raise UsageError(f"--evaluations must be at least {len(fps) + 1} (the free parameters + 1), "
                         f"got {evaluations!r}")
    if sim_rate_hz is not None:
        from studyctl.engine.loop_rates import check_sim_rate

        check_sim_rate(sim_rate_hz)
    if workers is None:
        workers = min(replicates, os.cpu_count() or 1)
    if not isinstance(workers, int) or workers < 1:
        raise UsageError(f"--workers must be a whole number ≥ 1, got {workers!r}")
    paper = int(proto.participants.target_n or participants)
    out_path = Path(out) if out is not None else Path(f"{pid}.calibrated.yaml")
    if out_path.suffix not in (".yaml", ".yml"):
        raise UsageError(f"--out {out_path}: the population file ends in .yaml")
    if out_path.exists() and out_path.is_dir():
        raise UsageError(f"--out {out_path} is a folder; give the population file to write (e.g. {pid}.yaml)")
    return CalibrationSpec(
        protocol_id=pid, protocol_text=proto.source_text, plan=plan, population=pop, targets=tset, free=fps,
        seed=check_master_seed(seed), participants=participants, paper_participants=paper, replicates=replicates,
        evaluations=evaluations, out=out_path, scheduler=scheduler, workers=workers, sim_rate_hz=sim_rate_hz,
    )


def _plan_ref(targets: str | Path | None, pid: str) -> str:
    """The analysis plan: the targets file's ``plan:`` (relative to that file), else the protocol's shipped one."""
    if targets is None or not Path(targets).is_file():
        return pid
    from studyctl.populations.targets import read_targets_data

    # Read as the targets loader reads it (size, UTF-8, alias and depth limits; yaml.safe_load raised
    # RecursionError on deep nesting), and before the plan, which imports the statistics: a hostile
    # targets file is one error line from a small process (issue 19).
    data = read_targets_data(targets)
    ref = data.get("plan") if isinstance(data, dict) else None
    if not isinstance(ref, str) or not ref:
        return pid
    near = Path(targets).parent / ref
    return str(near) if near.is_file() else ref
