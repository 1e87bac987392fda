"""The feedback-loop rates a simulated study runs at, and the one default cap on them.

A reduced loop rate is for virtual participants only: the simulated device still integrates at its own rate
under the held command, and ``studyctl bench simrate`` measures what the cap changes against the protocol's rates.
``demo``, ``simulate``, ``power`` and ``calibrate`` all take :data:`SIM_RATE_HZ` as their default cap, from here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from studyctl.errors import UsageError

if TYPE_CHECKING:
    from studyctl.engine.factory import PluginFactory
    from studyctl.engine.plan import SessionPlan

# The command modules read SIM_RATE_HZ as an option's default when they are registered, so this module imports
# nothing heavy at its top: the plugin factory, planner and session runner (numpy, pandas) load when a rate is asked.

#: Default loop-rate cap of simulated sessions (controllers that allow it: the 1 kHz tissue and needle controllers);
#: ``--full-rate`` lifts it. Seed 001 at 250 Hz moves no metric beyond the 1 kHz seeds' own spread (``simrate``).
SIM_RATE_HZ = 250.0


def check_sim_rate(sim_rate_hz: float) -> float:
    """``sim_rate_hz`` if it is a usable simulation loop rate (a positive, finite number of Hz)."""
    if not (0 < sim_rate_hz < float("inf")):
        raise UsageError(f"--sim-rate-hz (the simulation loop rate) must be a positive number of Hz, got {sim_rate_hz}")
    return float(sim_rate_hz)


@dataclass(frozen=True)
class FeedbackLoop:
    """A condition's feedback loop: its controller, the rate it runs at, and whether a simulated session may run
    it slower (``Controller.rate_adjustable``)."""

    controller: str
    rate_hz: float
    adjustable: bool


def feedback_loops(plan: SessionPlan, factory: PluginFactory) -> dict[str, FeedbackLoop]:
    """The feedback loop of each condition that has one (a controller, not a manual condition)."""
    from studyctl.engine.session import condition_rate

    return {cid: FeedbackLoop(cond.controller, condition_rate(cond, factory),
                              bool(getattr(factory.load("controller", cond.controller), "rate_adjustable", False)))
            for cid, cond in plan.conditions.items() if cond.controller and not cond.manual}


def simulation_rates(plan: SessionPlan, factory: PluginFactory, sim_rate_hz: float) -> dict[str, float]:
    """Loop rate per condition for a simulated session capped at ``sim_rate_hz``: the conditions whose
    controller is ``rate_adjustable`` and faster than the cap (manual conditions and fixed-rate controllers
    keep their rates)."""
    return _slowed(feedback_loops(plan, factory), check_sim_rate(sim_rate_hz))


def sample_plan(protocol: Any) -> SessionPlan:
    """The session plan of the first stratum's first sequence (every person's plan has the same conditions)."""
    from studyctl.engine.planning import plan_for_participant
    from studyctl.protocol import Planner

    schedule = Planner(protocol).expand(seed=0, slot=0, stratum=protocol.stratum_ids[0])
    return plan_for_participant(protocol, schedule)


def protocol_loops(protocol: Any) -> dict[str, FeedbackLoop]:
    """Per condition with a controller, its feedback loop as the protocol states it."""
    from studyctl.engine.factory import EntryPointFactory

    return feedback_loops(sample_plan(protocol), EntryPointFactory())


def loop_rates(protocol: Any, sim_rate_hz: float | None) -> dict[str, float]:
    """Per condition with a controller, the loop rate its simulated sessions run at under the cap ``sim_rate_hz``
    (None: the protocol's rates)."""
    return capped_rates(protocol, sim_rate_hz)[0]


def slowing_cap(protocol: Any, sim_rate_hz: float | None) -> float | None:
    """``sim_rate_hz`` when it slows one of ``protocol``'s feedback loops, else None: the sessions then run at the
    protocol's rates (no rate-adjustable loop faster than the cap, e.g. seed 000's 50 Hz controllers)."""
    return capped_rates(protocol, sim_rate_hz)[1]


def capped_rates(protocol: Any, sim_rate_hz: float | None) -> tuple[dict[str, float], float | None]:
    """:func:`loop_rates` and :func:`slowing_cap` of ``protocol`` under ``sim_rate_hz`` together, from one build
    of its loops (building them plans a session and loads every controller)."""
    loops = protocol_loops(protocol)
    slowed = {} if sim_rate_hz is None else _slowed(loops, check_sim_rate(sim_rate_hz))
    rates = {cid: loop.rate_hz for cid, loop in loops.items()} | slowed
    return rates, (float(sim_rate_hz) if slowed else None)


def default_sim_rate(protocol: Any) -> float | None:
    """The default cap for ``protocol``: :data:`SIM_RATE_HZ` when it slows one of its loops, else None (the
    protocol's rates; e.g. seed 000's 50 Hz controllers, which are not rate-adjustable)."""
    return slowing_cap(protocol, SIM_RATE_HZ)


def _slowed(loops: dict[str, FeedbackLoop], cap: float) -> dict[str, float]:
    """The rule of a cap, on loops already built: the rate-adjustable loops faster than ``cap`` run at it."""
    return {cid: cap for cid, loop in loops.items() if loop.adjustable and loop.rate_hz > cap}

