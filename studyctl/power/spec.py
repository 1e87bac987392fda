"""What a power analysis simulates, checked before any work starts.

:func:`prepare_power` turns the command's inputs (protocol, plan, sample sizes, replicates, seed,
population) into a :class:`PowerSpec`, raising a clear one-line error for anything that cannot work:
a plan of another protocol or of a CSV file, plan conditions or groups the protocol does not have, a
plan without a hypothesis test, a sample size below the number of counterbalancing sequences, a
population knob that names an unknown parameter, condition or group, a missing plugin.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

from studyctl import __version__
from studyctl.analysis import AnalysisPlan, load_plan
from studyctl.analysis.catalog import TESTS
from studyctl.engine.factory import EntryPointFactory
from studyctl.engine.loop_rates import check_sim_rate, loop_rates, protocol_loops, sample_plan, slowing_cap
from studyctl.engine.preflight import preflight
from studyctl.errors import UsageError
from studyctl.power.population import Population, population_model
from studyctl.power.seeds import check_master_seed
from studyctl.power.target import check_complete_blocks, check_target
from studyctl.protocol import Planner, Protocol, load_protocol, load_protocol_text, resolve_protocol
from studyctl.resources import shipped_names, shipped_plan_for

#: Row kinds of a plan's result that are hypothesis tests (intervals and descriptives are not).
TEST_KINDS = ("omnibus", "two_sample", "pairwise", "posthoc")
MAX_REPLICATES = 1_000_000


@dataclass(frozen=True)
class PowerSpec:
    """Everything a replicate needs; picklable, so it can be sent to Dask workers.

    ``protocol_text`` is the protocol's exact text (each replicate stores it with its throwaway study);
    ``plan`` the validated :class:`~studyctl.analysis.AnalysisPlan`; ``memory_limit`` the cap in bytes
    on a worker process's resident memory (None: no cap).
    """

    protocol_name: str
    protocol_text: str
    protocol_sha256: str
    study_id: str
    plan: Any  # AnalysisPlan (pydantic model)
    plan_sha256: str
    population: Population
    seed: int
    sizes: tuple[int, ...]
    replicates: int
    sequences: int | None
    memory_limit: int | None = None
    #: The virtual people's between-subject traits (a studyctl.populations.TraitPopulation; the knobs above shift
    #: on top of each person's drawn traits). None: every person starts from the participant's defaults.
    traits: Any = None
    #: Loop-rate cap of the simulated sessions (engine.api.run_session's sim_rate_hz); None: the protocol's rates.
    sim_rate_hz: float | None = None
    #: Target power (``--target``): the run reports per test the smallest size reaching it; None: no target.
    target: float | None = None

    def fingerprint(self) -> dict[str, Any]:
        """What every replicate's result depends on (a results file from other settings cannot be reused)."""
        return {
            "studyctl": __version__,
            "protocol_sha256": self.protocol_sha256,
            "plan_sha256": self.plan_sha256,
            "population": self.population.to_dict(),
            "traits_sha256": None if self.traits is None else self.traits.sha256,
            "sim_rate_hz": self.sim_rate_hz,
            "seed": self.seed,
        }

    def load_protocol(self) -> Any:
        """The protocol parsed from the spec's own text (what a worker process has; never the file again)."""
        return load_protocol_text(self.protocol_text, self.protocol_name)

    def loop_rates(self) -> dict[str, float]:
        """Per condition with a controller, the loop rate (Hz) the simulated sessions run at (the cap applied)."""
        return dict(self._loop_rates)  # a copy: the cached one stays as computed

    @cached_property
    def _loop_rates(self) -> dict[str, float]:
        # A run asks 3-4 times (the printed line, the figure's note, power_run.json, the result); the protocol is
        # parsed and planned once per spec. cached_property writes the instance's __dict__, past the frozen
        # __setattr__; dataclasses.replace builds a new spec, so a changed cap is never answered from this one.
        return loop_rates(self.load_protocol(), self.sim_rate_hz)

    def tasks(self) -> list[tuple[int, int]]:
        """Every (sample size, replicate index) of the run, smallest sample size first."""
        return [(n, r) for n in self.sizes for r in range(self.replicates)]


def parse_sizes(text: str | list[int] | tuple[int, ...]) -> tuple[int, ...]:
    """``"8,12,16"`` (or a sequence) → sorted unique positive sample sizes (UsageError otherwise)."""
    items = text.split(",") if isinstance(text, str) else list(text)
    sizes = []
    for item in items:
        raw = item.strip() if isinstance(item, str) else item
        if raw == "":
            continue
        try:
            n = int(raw)
            if isinstance(raw, float) and raw != n:
                raise ValueError
        except (TypeError, ValueError):
            raise UsageError(f"--participants: {raw!r} is not a whole number; give sizes like 8,12,16,20,25") from None
        if n < 1:
            raise UsageError(f"--participants: sample size {n} must be at least 1")
        sizes.append(n)
    if not sizes:
        raise UsageError("--participants: give at least one sample size, e.g. 8,12,16,20,25")
    if len(set(sizes)) != len(sizes):
        dup = sorted({n for n in sizes if sizes.count(n) > 1})
        raise UsageError(f"--participants: sample size(s) {', '.join(map(str, dup))} given twice")
    return tuple(sorted(sizes))


def parse_memory(text: str | int | None) -> int | None:
    """``"2GiB"``, ``"1500MB"``, ``"0"``/``"none"`` (no cap) or a number of bytes → bytes or None."""
    if text is None:
        return None
    if isinstance(text, int):
        return None if text == 0 else text
    raw = str(text).strip()
    if raw.lower() in ("0", "none", "off"):
        return None
    units = {
        "": 1,
        "b": 1,
        "kb": 10**3,
        "mb": 10**6,
        "gb": 10**9,
        "tb": 10**12,
        "kib": 2**10,
        "mib": 2**20,
        "gib": 2**30,
        "tib": 2**40,
    }
    number = raw.rstrip("kKmMgGtTiIbB")
    unit = raw[len(number) :].strip().lower()
    try:
        value = float(number)
    except ValueError:
        value = -1.0
    if unit not in units or not value > 0:
        raise UsageError(f"--memory-limit {raw!r}: use a size like 2GiB, 1500MB or 0 for no cap")
    limit = int(value * units[unit])
    if limit < 256 * 2**20:
        raise UsageError(f"--memory-limit {raw!r} is below 256 MiB; a worker needs more to run a study")
    return limit


def _plan_digest(plan: Any) -> str:
    data = plan.model_dump(mode="json")
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()


def check_plan_matches(plan: Any, protocol: Any, protocol_label: str) -> None:
    """Raise UsageError unless ``plan`` analyses ``protocol`` from its database (see module docs)."""
    where = plan.source_path or plan.title
    if plan.study != protocol.study.id:
        raise UsageError(
            f"plan {where} analyses protocol {plan.study!r}, but {protocol_label} is protocol "
            f"{protocol.study.id!r}; use that protocol's plan (--plan {protocol.study.id})"
        )
    if plan.data.source != "database":
        raise UsageError(
            f"plan {where} reads its data from a CSV file ({plan.data.path}); a power analysis "
            "simulates studies: use a plan with data: {source: database}"
        )
    known = list(protocol.condition_ids)
    for c in plan.condition_ids:
        if c not in known:
            raise UsageError(
                f"plan {where}: condition {c!r} is not in protocol {protocol.study.id!r} (it has {', '.join(known)})"
            )
    strata = list(protocol.stratum_ids)
    for g in plan.group_ids:
        if g not in strata:
            raise UsageError(
                f"plan {where}: group {g!r} is not a stratum of protocol {protocol.study.id!r} "
                f"(it has {', '.join(strata)})"
            )

    hypothesis = [t.id for t in plan.tests if TESTS[t.test].design not in ("descriptive", "proportion")]
    if not hypothesis:
        raise UsageError(
            f"plan {where} has no hypothesis test (only intervals or descriptives); power is the "
            "chance a test is significant: add a test such as kruskal_wallis or rank_sum"
        )


def _preflight(protocol: Any) -> None:
    """Plugins the simulated sessions need exist (PluginError names the missing one)."""
    preflight(sample_plan(protocol), EntryPointFactory(), virtual=True, person_participant=False).raise_if_missing()


def _check_rate_cap(protocol: Any, sim_rate_hz: float | None) -> float | None:
    """``sim_rate_hz`` if it slows at least one of ``protocol``'s loops (UsageError otherwise: a cap that changes
    nothing would only key the results and pools apart from the same simulation's)."""
    if sim_rate_hz is None:
        return None
    check_sim_rate(sim_rate_hz)
    cap = slowing_cap(protocol, sim_rate_hz)
    if cap is not None:
        return cap
    loops = {loop.controller: (loop.rate_hz, loop.adjustable) for loop in protocol_loops(protocol).values()}
    seen = "; ".join(f"{name} {rate:g} Hz{'' if adj else ', not rate-adjustable'}"
                     for name, (rate, adj) in sorted(loops.items()))
    faster = [rate for rate, adj in loops.values() if adj]
    fix = (f"give a rate below {max(faster):g} Hz or leave --sim-rate-hz out" if faster
           else "leave --sim-rate-hz out (this study runs at its protocol's rates)")
    raise UsageError(f"--sim-rate-hz {sim_rate_hz:g}: slows no feedback loop of protocol {protocol.study.id!r} "
                     f"({seen or 'no controller'}); {fix}")


def prepare_power(
    protocol: str | Path | Protocol,
    plan: str | Path | AnalysisPlan | None = None,
    *,
    sizes: str | tuple[int, ...] | list[int],
    replicates: int,
    seed: int | None = None,
    population: Population | None = None,
    memory_limit: str | int | None = None,
    traits: Any = "shipped",
    target: float | None = None,
    sim_rate_hz: float | None = None,
) -> PowerSpec:
    """Check every input of a power analysis and return the spec the replicates run from.

    Parameters
    ----------
    protocol
        A shipped protocol name, a protocol file, or a protocol the caller has loaded (not read again).
    plan
        A shipped plan name, a plan file or a loaded plan; it must analyse that protocol from its database.
        None: the shipped plan of the same name as a shipped protocol (UsageError when the protocol has none).
    sizes
        Sample sizes (``"8,12,16"`` or a sequence); each at least the number of counterbalancing
        sequences, so every sequence is used.
    replicates
        Replicate studies per sample size.
    seed
        Master seed (default: the protocol's ``study.seed``).
    population
        The population knobs (default: none, the virtual participant as the protocol configures it).
    memory_limit
        Cap on each worker's memory (``"2GiB"``; None/0: none).
    traits
        The population the virtual people are drawn from: ``"shipped"`` (default: the protocol's shipped,
        calibrated population when there is one), a population file, a ``TraitPopulation``, or None.
    target
        Target power in (0, 1): every size must then complete the counterbalancing blocks
        (:func:`studyctl.power.target.check_complete_blocks`), so the answer is a balanced design.
    sim_rate_hz
        Run the rate-adjustable feedback loops (the 1 kHz tissue and needle controllers) at most this fast
        (``run_session``'s ``sim_rate_hz``; what it changes: ``studyctl bench simrate``). None: the protocol's rates.
        A cap that slows none of the protocol's loops is refused.

    Raises
    ------
    UsageError, ProtocolError, NotFoundError, PluginError
        For anything that would fail later, before any simulation starts.
    """
    if isinstance(protocol, Protocol):
        proto, path = protocol, Path(protocol.path)
    else:
        path = resolve_protocol(protocol)
        proto = load_protocol(path)
    if plan is None:
        plan = shipped_plan_for(path)
        if plan is None:
            raise UsageError(f"--plan is needed: {protocol} is not a shipped protocol with a shipped analysis plan "
                             f"of the same name; give --plan FILE (an analysis plan for this protocol) or a shipped "
                             f"plan name ({', '.join(shipped_names('analysis'))})")
    loaded = plan if isinstance(plan, AnalysisPlan) else load_plan(plan)
    given = str(path) if isinstance(protocol, Protocol) else str(protocol)
    label = given if given in (proto.study.id, str(path)) else f"{given} ({path})"
    check_plan_matches(loaded, proto, label)
    size_tuple = parse_sizes(sizes)
    if isinstance(replicates, bool) or not isinstance(replicates, int) or not 1 <= replicates <= MAX_REPLICATES:
        raise UsageError(f"--replicates must be a whole number from 1 to {MAX_REPLICATES}, got {replicates!r}")
    planner = Planner(proto)
    nseq = None if planner.sequences is None else len(planner.sequences)
    if nseq is not None and size_tuple[0] < nseq:
        low = [str(n) for n in size_tuple if n < nseq]
        raise UsageError(
            f"--participants {', '.join(low)}: below the {nseq} counterbalancing sequences of "
            f"protocol {proto.study.id!r} ({proto.counterbalance.scheme}); with fewer participants "
            f"some orders are never used and the design is unbalanced: use at least {nseq}"
        )
    target = check_target(target)
    if target is not None:
        check_complete_blocks(proto, size_tuple)
    master = check_master_seed(
        proto.study.seed if seed is None and proto.study.seed is not None else (0 if seed is None else seed)
    )
    population = population or Population()
    population_model(population, proto)
    from studyctl.populations import population_for

    traits = population_for(proto, traits)
    _preflight(proto)
    sim_rate_hz = _check_rate_cap(proto, sim_rate_hz)
    return PowerSpec(
        protocol_name=Path(path).stem,
        protocol_text=proto.source_text,
        protocol_sha256=proto.sha256,
        study_id=proto.study.id,
        plan=loaded,
        plan_sha256=_plan_digest(loaded),
        population=population,
        seed=master,
        sizes=size_tuple,
        replicates=int(replicates),
        sequences=nseq,
        memory_limit=parse_memory(memory_limit),
        traits=traits,
        sim_rate_hz=sim_rate_hz,
        target=target,
    )
