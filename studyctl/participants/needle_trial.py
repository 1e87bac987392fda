"""What the virtual needle operator holds during one trial: its phase, its current movement and its state.

:class:`Phase` names where it is in a trial (the operator has one handler per phase), :class:`MinJerk` and
:class:`Line` are the two kinds of movement it makes, :class:`TrialState` everything it keeps from
``begin_trial`` to the finish. No decisions here: see :mod:`~studyctl.participants.needle_operator`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum, auto
from typing import Any

import numpy as np

from studyctl.participants.ct_reader import CTReading
from studyctl.participants.needle_params import Vec
from studyctl.participants.needle_perception import AxialCueDetector, Plan, PositionSense
from studyctl.plugins.interfaces import Action, TrialInfo

__all__ = ["Line", "MinJerk", "Phase", "TrialState", "learn_trust", "norm"]


class Phase(Enum):
    """Where the operator is in a trial; :meth:`VirtualNeedleOperator._step` has one handler for each."""

    PLAN = auto()  # no plan yet: ask for the planning scan (or look at the live view)
    READ = auto()  # holding still, waiting for a scan and reading it
    APPROACH = auto()  # free-space reach to the pre-entry point above the incision
    INSERT = auto()  # advancing along a line (insertion, or a correction after a scan)
    HOLD = auto()  # stopped, button released, settling
    JUDGE = auto()  # is the tip in the tumour? (entered right after the confirming scan is read)
    FINISH = auto()  # about to press finish
    DONE = auto()  # finished; waits for the trial to end


@dataclass
class MinJerk:
    """A free-space reach: minimum-jerk reference from ``a`` to ``b`` over ``T`` s, then maybe on to ``then``."""

    a: Vec
    b: Vec
    T: float
    then: Vec | None = None
    elapsed: float = 0.0


@dataclass
class Line:
    """Advance the reference until the believed tip is ``stop`` mm past ``origin`` along ``axis``.

    With ``aim`` the reference heads for that point (re-aimed at every decision, so an offset seen on an
    image is steered out), else it moves along ``dir``. The reference may lead the believed tip (tissue
    resists, the hand is compliant) by at most 5 mm (``max_ref``): beyond that the push is given up.
    """

    dir: Vec
    axis: Vec
    aim: Vec | None
    origin: Vec
    stop: float
    v: float
    max_ref: float
    ref_s: float
    moving_s: float = 0.0


@dataclass
class TrialState:
    """Everything the operator holds during one trial (made anew by ``begin_trial``)."""

    info: TrialInfo
    ratio: float  # device ticks per decision (≥ 1; need not be whole, see ``VirtualNeedleOperator.act``)
    dt: float  # seconds this decision's command is held: ticks to the next decision / loop rate
    realtime: bool
    scans_allowed: bool
    v_ins: float
    v_fin: float
    v_app: float
    read_s: float  # looking at a scan, this trial
    z: np.ndarray  # pre-drawn noise: a few rows per decision
    ref: Vec  # where it wants its (believed) tip
    prev_ref: Vec
    last_cmd: Vec
    action: Action
    record: dict[str, Any]  # what it will remember of this trial
    sense: PositionSense
    cue: AxialCueDetector = field(default_factory=AxialCueDetector)
    tick: int = -1  # loop ticks since the trial began (the first call is tick 0)
    next_tick: int = 0  # the tick of the next decision
    decisions: int = 0
    zi: int = 0
    wobble: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    speed_dev: float = 0.0
    axis: Vec = (0.0, 0.0, -1.0)
    button: float = 1.0
    phase: Phase = Phase.PLAN
    next_phase: Phase = Phase.PLAN
    busy_until: float = 0.0
    frame: Mapping[str, Any] | None = None
    last_view_t: float = -1e9
    # live-view readings not yet acted on (``realtime_view_delay_s``), oldest first: (time to act on it, reading)
    pending_views: deque[tuple[float, CTReading]] = field(default_factory=deque)
    plan: Plan | None = None
    move: MinJerk | Line | None = None
    react_until: float = 0.0
    scans: int = 0
    stop_reason: str = ""
    felt_radial_s: float = 0.0
    radial_onset: Vec = (0.0, 0.0, 0.0)  # felt hand position where the current lateral push was first felt
    radial_onset_n: float = 0.0  # and the push it felt there (N)
    corrections: int = 0
    guided: bool = False  # this insertion already runs at the guided speed
    line_checked: bool = False  # the one scan before feeling for the tumour was taken
    cue_on_correction: bool = False  # the last cue came while correcting towards a target seen on an image
    probing: bool = False  # pushing sideways over the incision to feel the channel (``probe_mm``)
    blind_at: Vec | None = None  # felt hand position of the last scan that did not show the tip

    def noise(self) -> list[float]:
        # Python floats (the same doubles): a numpy row's scalars made the reference, the wobble and the felt
        # forces numpy-scalar arithmetic from there on (a 250 Hz seed-001 simulate -n 2 took 7-17 % more CPU).
        z = self.z[self.zi].tolist()
        self.zi = (self.zi + 1) % len(self.z)
        return z

    def need_plan(self) -> Plan:
        if self.plan is None:
            raise RuntimeError("virtual_needle_operator: acting on a plan before a scan produced one")
        return self.plan


def learn_trust(trust: dict[str, float], key: str, rate: float, confirmed: bool) -> None:
    """Move trust in a cue a ``rate`` fraction of the way towards 1 (confirmed) or 0 (misled)."""
    old = trust.get(key, 0.0)
    trust[key] = old + rate * ((1.0 if confirmed else 0.0) - old)


def norm(v: Vec) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
