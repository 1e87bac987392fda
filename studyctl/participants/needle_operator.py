"""A virtual operator for the CT-guided needle insertion of seed 001.

It acts only through what a person at the device has: the CT frames it requests (or the real-time view),
the force on its hand and the handle position it feels, and its own motor system. It never reads the
scene. What it does, and why each part is there:

* **Plans from a scan.** It reads the tumour, the skin marker at the incision point and the needle tip
  from the frame's pixels (:func:`~studyctl.participants.ct_reader.read_ct`) and plans a straight path
  from the marker to the tumour. It points the pen along it with an orientation error.
* **Steers with a noisy body.** Its hand set-point follows minimum-jerk approach and constant-speed
  insertion references, with a lateral wobble (Ornstein–Uhlenbeck) and speed fluctuations. Its sense of
  where the hand is drifts with movement (a proprioceptive random walk); a scan shows the true tip and
  resets that error to the image's resolution, which is what makes scans worth their time.
* **Feels the forces through the simulated device.** The hand is a spring-damper on the handle mass, so
  tissue and guidance forces move it. It follows a perceivable radial force (a guidance cue), and watches
  the axial force for a rise above its running baseline (Weber fraction plus an absolute threshold): an
  enhanced tumour (ES/ESG) gives such a cue, the compliant one of BL does not. A cue means "at the tumour";
  it stops, reacting after a delay, and relaxes its push.
* **Decides when to scan** from its own uncertainty (growing with movement, reset by scans, the lateral
  part reset by a perceived guidance force): before entering if unsure of the entry point, when it thinks
  it is close to the target unless it has learnt in this scenario that a force cue marks the target, and
  to confirm before finishing unless it is already sure. Reading a scan takes time, during which it holds
  (button released: maintain mode).
* With a **real-time view** it reads the view a few times a second instead of requesting scans.

Outcomes (scans, duration, errors) are therefore whatever happens when this behaviour meets the
controller, the device and the scene; no metric is written here. Every parameter is declared with unit, range
and source in :mod:`~studyctl.participants.needle_params`; a person's traits (speed, reading time, position
sense, force thresholds, caution, how fast it learns to trust a cue) arrive as constructor params drawn by a
population file, and each trial varies its pace around them with the trial's random stream.

Code map: :class:`OperatorParams` (the checked ``PARAMS``), :class:`TrialState` (everything held during a
trial), :class:`Phase` with one handler per phase (``_step``); what it senses is in
:mod:`~studyctl.participants.needle_perception`, how it answers questionnaires in
:mod:`~studyctl.participants.needle_questionnaire`.

Questionnaire answers are judged from the session's stored trial record the engine passes with each item
(durations, scans, timeouts, each scenario's view), never from memory that a resumed process would lack.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum, auto
from typing import Any

import numpy as np

from studyctl.participants.ct_reader import CTReading, read_ct
from studyctl.participants.needle_params import DEFAULTS, PARAMS, OperatorParams, Vec
from studyctl.participants.needle_perception import AxialCueDetector, Plan, PositionSense, feel_force
from studyctl.participants.needle_questionnaire import judge_item
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo

__all__ = ["DEFAULTS", "PARAMS", "OperatorParams", "Phase", "VirtualNeedleOperator"]

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
    every: int  # device ticks per decision
    dt: float  # seconds per decision
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
    tick: int = 0
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

    def noise(self) -> np.ndarray:
        z = self.z[self.zi]
        self.zi = (self.zi + 1) % len(self.z)
        return z

    def need_plan(self) -> Plan:
        if self.plan is None:
            raise RuntimeError("virtual_needle_operator: acting on a plan before a scan produced one")
        return self.plan


def _learn(trust: dict[str, float], key: str, rate: float, confirmed: bool) -> None:
    """Move trust in a cue a ``rate`` fraction of the way towards 1 (confirmed) or 0 (misled)."""
    old = trust.get(key, 0.0)
    trust[key] = old + rate * ((1.0 if confirmed else 0.0) - old)


def _norm(v: Vec) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


class VirtualNeedleOperator(Participant):
    """Virtual participant for seed 001 (entry point ``virtual_needle_operator``); params: :data:`PARAMS`."""

    name = "virtual_needle_operator"
    virtual = True

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        super().__init__(params)
        self.p = OperatorParams.from_mapping(params)
        self.history: list[dict[str, Any]] = []  # what it remembers of its own trials
        # learnt per scenario label (0…1, trusted from 0.5): that a force cue marks the target, that the felt
        # guidance channel keeps the tip on the path
        self.trust_cue: dict[str, float] = {}
        self.trust_guide: dict[str, float] = {}
        # the stiffness (N/m) it has felt the guidance channel to have, per scenario label (force rise over sideways
        # travel): sets how much faster it dares to advance inside the channel (:meth:`_channel_speed`)
        self.wall_k: dict[str, float] = {}
        self.s: TrialState | None = None

    # ------------------------------------------------------------------ session and trial set-up
    def memory(self) -> dict[str, Any]:
        """What it has learnt to trust per scenario, and its own trial record, stored by the engine with each
        finished trial: a session resumed in a new process goes on as the uninterrupted one would."""
        return {"trust_cue": dict(self.trust_cue), "trust_guide": dict(self.trust_guide),
                "wall_k": dict(self.wall_k), "history": [dict(r) for r in self.history]}

    def recall(self, memory: Mapping[str, Any]) -> None:
        self.trust_cue = {str(k): float(v) for k, v in (memory.get("trust_cue") or {}).items()}
        self.trust_guide = {str(k): float(v) for k, v in (memory.get("trust_guide") or {}).items()}
        self.wall_k = {str(k): float(v) for k, v in (memory.get("wall_k") or {}).items()}
        self.history = [dict(r) for r in (memory.get("history") or [])]

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        p = self.p
        # this trial's own pace: within-person variation around the person's speed and reading time
        vary = rng.standard_normal(2)
        speed = p.insert_speed_mm_s * math.exp(p.speed_trial_cv * float(vary[0]))
        every = max(1, round(info.rate_hz / p.decision_hz))
        dt = every / info.rate_hz
        realtime = info.visual == "realtime"
        if realtime:
            speed *= p.realtime_speed_gain
        n = 4 * (int(info.time_limit_s / dt) + 16)
        z = rng.standard_normal((n, 8))
        home = p.home
        self.s = TrialState(
            info=info,
            every=every,
            dt=dt,
            realtime=realtime,
            scans_allowed=info.visual == "on_request",
            v_ins=speed,
            v_fin=speed * p.final_speed_ratio,
            v_app=speed * p.approach_speed_ratio,
            read_s=p.scan_read_s * math.exp(p.read_trial_cv * float(vary[1])),
            z=z,
            ref=home,
            prev_ref=home,
            last_cmd=home,
            action=Action({}),
            record={"condition": info.condition, "visual": info.visual, "cue": False, "wall": False,
                    "radial_felt_s": 0.0},
            sense=PositionSense(3.0),
            tick=every - 1,  # decide on the first call
        )
        self.s.action = self._make_action(home, ())

    @property
    def _st(self) -> TrialState:
        if self.s is None:
            raise RuntimeError("virtual_needle_operator: acting before begin_trial")
        return self.s

    # ------------------------------------------------------------------ the tick
    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        st = self._st
        if "scan" in percept and percept["scan"] is not None:
            st.frame = percept["scan"]
            if st.busy_until == math.inf:
                st.busy_until = t + self._read_time()
        st.tick += 1
        if st.tick < st.every:
            return st.action
        st.tick = 0
        requests = self._decide(t, percept)
        cmd = self._command(percept)
        st.action = self._make_action(cmd, ())
        if requests:  # requests go out once; the ticks until the next decision repeat only the inputs
            return Action(st.action.inputs, requests)
        return st.action

    def _decide(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        st, p = self._st, self.p
        # position sense drifts with intended movement
        z = st.noise()
        moved = math.dist(st.ref, st.prev_ref)
        st.prev_ref = st.ref
        st.sense.drift(moved, p.proprio_drift, z)
        self._perceive(t, percept)
        if st.realtime and "view" in percept and t - st.last_view_t >= p.visual_period_s:
            st.last_view_t = t
            self._take_image(percept["view"], percept)
        if t > st.info.time_limit_s - 3.0 and st.phase not in (Phase.FINISH, Phase.DONE):
            return self._begin_finish(percept, t, "time")
        return self._step(t, percept)

    def _step(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        """One handler per phase."""
        match self._st.phase:
            case Phase.PLAN:
                return self._on_plan(t)
            case Phase.READ:
                return self._on_read(t, percept)
            case Phase.APPROACH:
                return self._on_approach(t, percept)
            case Phase.INSERT:
                return self._on_insert(t, percept)
            case Phase.HOLD:
                return self._on_hold(t, percept)
            case Phase.JUDGE:
                return self._judge(t, percept)
            case Phase.FINISH:
                return self._on_finish(t)
            case Phase.DONE:
                return ()

    def _read_time(self) -> float:
        """Looking at a scan: planning on the first takes longer; a check while a haptic cue of this scenario
        is trusted is a confirming glance (it knows what it expects to see)."""
        st, p = self._st, self.p
        if st.plan is None:
            return st.read_s + p.plan_read_extra_s
        if self._trusts_cue() or self._trusts_guide():
            return st.read_s * p.confirm_read_ratio
        return st.read_s

    def _trusts_cue(self) -> bool:
        return self.trust_cue.get(self._st.info.condition, 0.0) >= 0.5

    def _trusts_guide(self) -> bool:
        return self.trust_guide.get(self._st.info.condition, 0.0) >= 0.5

    def _probing_channel(self) -> bool:
        """Moving along the planned line (in tissue, or the last leg of the approach onto the incision), slowly
        sideways: a lateral push growing now comes from straying off the line, not from sweeping across it fast
        (where the channel's damper pushes back whatever its stiffness)."""
        st = self._st
        mv = st.move
        if st.phase is Phase.INSERT:
            return True
        return st.phase is Phase.APPROACH and isinstance(mv, MinJerk) and mv.then is None

    def _channel_speed(self) -> float:
        """Advance speed inside a guidance channel it trusts.

        Its pace through tissue is set by the lateral accuracy it must keep by itself: its hand's slips grow with
        speed (signal-dependent motor noise, :meth:`_command`). A channel of stiffness k, felt against its own arm
        stiffness k_arm, lets a hand slip move the tip only k_arm/(k_arm + k) as far, so the same tip accuracy
        allows (1 + k/k_arm) times its speed, but never more than its free-reach speed (``approach_speed_ratio``).
        """
        st, p = self._st, self.p
        k = self.wall_k.get(st.info.condition, 0.0)
        return st.v_ins * min(p.approach_speed_ratio, 1.0 + k / p.arm_stiffness_n_per_m)

    # ------------------------------------------------------------------ phase handlers
    def _on_plan(self, t: float) -> tuple[Request, ...]:
        st = self._st
        if st.realtime:
            # it looks at the live view with the button released (maintain mode) as it would read a scan: pressed,
            # the guidance would pull its waiting hand towards the planned line, sideways into the liver
            st.button = 0.0
            if st.plan is not None:  # the live view showed everything: look at it, then go
                st.phase, st.next_phase = Phase.READ, Phase.APPROACH
                st.busy_until = t + st.read_s + self.p.plan_read_extra_s
            return ()
        return self._scan_then(t, Phase.APPROACH)

    def _on_read(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        st = self._st
        if t < st.busy_until:
            return ()
        if st.frame is not None:
            self._take_image(st.frame, percept)
            st.frame = None
        if st.plan is None:
            return self._scan_then(t, st.next_phase)
        return self._after_read(t, percept)

    def _on_approach(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        st = self._st
        mv = st.move
        if not isinstance(mv, MinJerk):
            return ()
        if mv.then is not None and mv.elapsed >= mv.T:
            self._start_reach(mv.b, mv.then, st.v_app)
            return ()
        if mv.elapsed >= mv.T + 0.3:
            st.move = None
            if st.scans_allowed and st.sense.sig_lat > self.p.entry_scan_mm:
                return self._scan_then(t, Phase.INSERT)
            return self._enter_insert(percept)
        return ()

    def _on_insert(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        st, p = self._st, self.p
        pl = st.need_plan()
        if st.cue.felt and st.react_until and t >= st.react_until:
            st.react_until = 0.0
            if abs(pl.depth(self._belief(percept)) - pl.length) > p.margin_mm + 2.0 * st.sense.sig_ax:
                # far from where the image put the tumour: a bump of the liver or of its own stop-and-go (stick-slip
                # near the stick band), not the tumour; it goes on and takes the new resistance as the liver's
                st.cue.felt = False
                st.cue.expect_change()
            else:
                # a force cue: stop, hold, relax the push
                st.cue_on_correction = st.stop_reason == "correct"
                return self._stop(t, percept, "cue")
        mv = st.move
        if not isinstance(mv, Line):
            return self._stop(t, percept, "blocked")
        b = self._belief(percept)
        o, d = mv.origin, mv.axis
        done = (b[0] - o[0]) * d[0] + (b[1] - o[1]) * d[1] + (b[2] - o[2]) * d[2]
        if done >= mv.stop:
            return self._stop(t, percept, st.stop_reason if st.stop_reason == "correct" else "depth")
        if mv.ref_s >= mv.max_ref:
            return self._stop(t, percept, "blocked")
        depth = pl.depth(b)
        if st.stop_reason == "depth" and depth >= pl.length - p.margin_mm and mv.v > st.v_ins:
            # near where the plan puts the tumour it feels for it at its own pace: sped up (a trusted channel or
            # cue), the tip would cross the 2.5 mm tumour faster than the cue can be felt and reacted to
            mv.v = st.v_ins
        sig_lat = st.sense.sig_lat
        if st.scans_allowed and sig_lat > p.recheck_mm and depth < pl.length - 10.0:
            st.stop_reason = "recheck"
            self._relax(percept)
            return self._scan_then(t, Phase.INSERT)
        if (
            st.scans_allowed
            and st.stop_reason == "depth"
            and self._trusts_cue()
            and depth >= pl.length - p.margin_mm
            and sig_lat > p.finish_mm
            and not st.line_checked
        ):
            # going by feel for the depth, but the tip must be on line to meet the small tumour: check once (a
            # drifting position sense would otherwise ask again after every mm: 21 scans in one simulated trial)
            st.line_checked = True
            st.stop_reason = "recheck"
            self._relax(percept)
            return self._scan_then(t, Phase.INSERT)
        if st.realtime and math.dist(b, pl.tumour) <= 0.5 * p.accept_mm:
            return self._stop(t, percept, "seen")
        return ()

    def _on_hold(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        st = self._st
        if t < st.busy_until:
            return ()
        if st.stop_reason == "cue" and not st.realtime:  # with a live view it looks instead
            # a trusted cue ends the trial only where the plan puts the tumour; elsewhere it is checked on a scan
            near = abs(st.need_plan().depth(self._belief(percept)) - st.need_plan().length) <= self.p.margin_mm
            if near and self._trusts_cue() and st.sense.sig_lat <= self.p.finish_mm:
                return self._begin_finish(percept, t, "cue")
        if st.realtime:
            return self._judge(t, percept)
        if st.stop_reason == "cue" and st.cue_on_correction and st.sense.sig_lat <= self.p.finish_mm:
            # it just saw the tumour close by, moved towards it and felt it: it judges from that, no new scan; the
            # cue came where the image had just put the tumour, which confirms it as well as a scan would
            return self._judge(t, percept, seen=False, learn=True)
        return self._scan_then(t, Phase.JUDGE)

    def _on_finish(self, t: float) -> tuple[Request, ...]:
        st = self._st
        if t < st.busy_until:
            return ()
        st.phase = Phase.DONE
        st.record.update(duration_s=t, scans=st.scans, corrections=st.corrections)
        self.history.append(dict(st.record))
        return (Request("finish"),)

    # ------------------------------------------------------------------ transitions
    def _after_read(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        """Act on a fresh image: start the approach, enter, or judge where the tip is."""
        st = self._st
        b = self._belief(percept)
        st.button = 1.0
        if st.next_phase is Phase.APPROACH:
            # reach the pre-entry point from further out along the path, so the tip never cuts the liver
            pl = st.need_plan()
            st.phase = Phase.APPROACH
            st.ref = b
            far = (pl.entry[0] - 20.0 * pl.u[0], pl.entry[1] - 20.0 * pl.u[1], pl.entry[2] - 20.0 * pl.u[2])
            self._start_reach(b, far, st.v_app, then=pl.entry)
            return ()
        if st.next_phase is Phase.INSERT:
            return self._enter_insert(percept)
        return self._judge(t, percept)

    def _enter_insert(self, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        st, p = self._st, self.p
        pl = st.need_plan()
        st.phase = Phase.INSERT
        st.button = 1.0
        b = self._belief(percept)
        st.ref = b
        trust = self._trusts_cue()
        if st.realtime:
            stop = pl.length
        elif trust:
            stop = pl.length + p.overshoot_mm
        else:
            stop = pl.length - p.margin_mm
        extra = stop - pl.length if stop > pl.length else 0.0
        u, tum = pl.u, pl.tumour
        aim = (tum[0] + extra * u[0], tum[1] + extra * u[1], tum[2] + extra * u[2])
        st.guided = self._trusts_guide()
        speed = self._channel_speed() if st.guided else st.v_ins
        self._start_line(b, u, pl.marker, stop, speed, aim=aim)
        st.stop_reason = "depth"
        return ()

    def _relax(self, percept: Mapping[str, Any]) -> None:
        """Stop pushing: the wanted position becomes where it feels the tip is."""
        st = self._st
        st.move = None
        st.ref = self._belief(percept)

    def _stop(self, t: float, percept: Mapping[str, Any], reason: str) -> tuple[Request, ...]:
        st = self._st
        self._relax(percept)
        st.button = 0.0
        st.stop_reason = reason
        st.phase = Phase.HOLD
        st.busy_until = t + 0.3
        return ()

    def _judge(self, t: float, percept: Mapping[str, Any], *, seen: bool = True,
               learn: bool = False) -> tuple[Request, ...]:
        """Is the tip in the tumour? If not, correct towards it (advancing or withdrawing slowly). A judgement on a
        fresh image (``seen``), or of a cue felt while steering to where an image had just shown the tumour
        (``learn``), teaches it whether the cue marked the tumour."""
        st, p = self._st, self.p
        pl = st.need_plan()
        b = self._belief(percept)
        tum = pl.tumour
        miss = math.dist(b, tum)
        if st.stop_reason == "cue" and (seen or learn):  # was the felt cue the tumour? learn from it
            _learn(self.trust_cue, st.info.condition, p.cue_trust_rate, miss <= 2.5 * p.accept_mm)
        # after each correction it grows more lenient: a looser placement is accepted rather than a fourth try
        if miss <= p.accept_mm * (1.0 + 0.5 * st.corrections):
            return self._begin_finish(percept, t, "in_tumour")
        st.phase = Phase.INSERT
        st.button = 1.0
        st.ref = b
        st.cue.felt = False
        # aim at the centroid, stop there (by belief) and look again
        d = ((tum[0] - b[0]) / miss, (tum[1] - b[1]) / miss, (tum[2] - b[2]) / miss)
        self._start_line(b, d, b, miss, st.v_fin)
        st.stop_reason = "correct"
        st.corrections += 1
        return ()

    def _begin_finish(self, percept: Mapping[str, Any], t: float, why: str) -> tuple[Request, ...]:
        st = self._st
        self._relax(percept)
        st.button = 0.0
        st.phase = Phase.FINISH
        st.busy_until = t + self.p.reaction_s + 0.3
        st.record["finish_reason"] = why
        return ()

    def _scan_then(self, t: float, next_phase: Phase) -> tuple[Request, ...]:
        """Hold still and request a scan (or just pause to look in real-time conditions)."""
        st = self._st
        st.button = 0.0
        st.phase = Phase.READ
        st.next_phase = next_phase
        if st.scans_allowed:
            st.scans += 1
            st.frame = None
            st.busy_until = math.inf  # until the frame arrives
            return (Request("scan"),)
        st.busy_until = t + 0.5 * st.read_s
        return ()

    # ------------------------------------------------------------------ seeing and feeling
    def _belief(self, percept: Mapping[str, Any]) -> Vec:
        st = self._st
        return st.sense.belief(percept, st.last_cmd)

    def _take_image(self, frame: Mapping[str, Any], percept: Mapping[str, Any]) -> CTReading:
        st = self._st
        reading = read_ct(frame, st.axis)
        if reading.tip_mm is not None:
            old = st.sense.see_tip(reading.tip_mm, st.sense.felt(percept, st.last_cmd), 0.3)
            c, r = st.sense.corr, st.ref
            # the belief moved, the hand did not: keep the set-point where it is
            st.ref = (r[0] + c[0] - old[0], r[1] + c[1] - old[1], r[2] + c[2] - old[2])
            st.prev_ref = st.ref
        if st.plan is None and reading.tumour_mm is not None and reading.marker_mm is not None:
            self._make_plan(reading.tumour_mm, reading.marker_mm)
        return reading

    def _make_plan(self, t: Vec, m: Vec) -> None:
        st = self._st
        d = (t[0] - m[0], t[1] - m[1], t[2] - m[2])
        length = _norm(d)
        u = (d[0] / length, d[1] / length, d[2] / length)
        # the pen is pointed along the plan with an orientation error
        z = st.noise()
        err = math.radians(self.p.orientation_sd_deg)
        a = (u[0] + err * z[0], u[1] + err * z[1], u[2] + err * z[2])
        n = _norm(a)
        st.axis = (a[0] / n, a[1] / n, a[2] / n)
        pre = self.p.preentry_mm
        st.plan = Plan(t, m, u, length, (m[0] - pre * u[0], m[1] - pre * u[1], m[2] - pre * u[2]))

    def _perceive(self, t: float, percept: Mapping[str, Any]) -> None:
        """Forces on the hand: follow a felt guidance push, and watch the axial force for a cue."""
        st, p = self._st, self.p
        felt = feel_force(percept, st.axis, p.force_noise_n, st.noise()) if "fx_n" in percept else None
        if felt is None:
            return
        cond = st.info.condition
        if st.button >= 0.5 and felt.radial_n > p.radial_threshold_n:
            # a felt lateral push: yield to it, and trust that it keeps the tip near the path
            g = p.follow_gain_mm_per_ns * st.dt
            r, (rx, ry, rz) = st.ref, felt.radial
            st.ref = (r[0] + g * rx, r[1] + g * ry, r[2] + g * rz)
            st.record["radial_felt_s"] += st.dt
            hand = st.sense.felt(percept, st.last_cmd)
            if st.felt_radial_s == 0.0:
                st.radial_onset = hand  # where the lateral push was first felt
                st.radial_onset_n = felt.radial_n
            st.felt_radial_s += st.dt
            if st.felt_radial_s > 0.2:
                st.sense.sig_lat = min(st.sense.sig_lat, p.finish_mm)
            # how far the hand went sideways while the push grew from just felt to wall_n: a short way is a stiff
            # wall (EG/ESG, 10x the BL spring), a long way a soft pull; stiffness is judged from force and travel
            o, a = st.radial_onset, st.axis
            dx, dy, dz = hand[0] - o[0], hand[1] - o[1], hand[2] - o[2]
            along = dx * a[0] + dy * a[1] + dz * a[2]
            travel = math.sqrt(max(0.0, dx * dx + dy * dy + dz * dz - along * along))
            if felt.radial_n > p.wall_n and travel <= p.wall_travel_mm and st.radial_onset_n < p.wall_n \
                    and self._probing_channel() and not st.record["wall"]:
                # the channel, felt while lining up over the incision or in tissue (once a trial), as a push that grew
                # from just noticeable (a push already strong when first felt says nothing of stiffness): it learns
                # to rely on it, and how stiff it is (force rise over the sideways travel; its felt position
                # resolves no finer than 0.05 mm)
                st.record["wall"] = True
                _learn(self.trust_guide, cond, p.guide_trust_rate, True)
                k_felt = 1000.0 * (felt.radial_n - st.radial_onset_n) / max(travel, 0.05)
                k_old = self.wall_k.get(cond)
                self.wall_k[cond] = k_felt if k_old is None else k_old + p.guide_trust_rate * (k_felt - k_old)
                if self._trusts_guide() and not st.guided and isinstance(st.move, Line) and st.stop_reason == "depth":
                    st.guided = True  # a firm channel, felt now: it need not fear lateral slips for the rest
                    st.move.v = max(st.move.v, self._channel_speed())
                    st.cue.expect_change()
        else:
            st.felt_radial_s = 0.0
        if st.button >= 0.5 and self._trusts_guide():
            # inside a channel it has felt to be firm (the guidance acts from before the incision on), it takes
            # the tip to be on the path laterally
            st.sense.sig_lat = min(st.sense.sig_lat, 0.9 * p.finish_mm)
        # axial cue: a rise above the running baseline while advancing deep in the liver
        mv = st.move
        if st.phase is Phase.INSERT and st.plan is not None and st.button >= 0.5 and isinstance(mv, Line):
            mv.moving_s += st.dt
            depth = st.plan.depth(self._belief(percept))
            if st.cue.update(felt.axial, depth, 0.5 * st.plan.length, mv.moving_s, st.dt,
                             p.force_threshold_n, p.force_weber):
                st.record["cue"] = True
                st.react_until = t + p.reaction_s

    # ------------------------------------------------------------------ motor output
    def _start_reach(self, start: Vec, goal: Vec, speed: float, *, then: Vec | None = None) -> None:
        """A free-space reach: minimum-jerk reference from ``start`` to ``goal``."""
        self._st.move = MinJerk(start, goal, max(math.dist(start, goal) / speed, 0.3), then)

    def _start_line(self, start: Vec, direction: Vec, origin: Vec, stop: float, v: float,
                    aim: Vec | None = None) -> None:
        """Advance the reference until the believed tip is ``stop`` mm past ``origin`` along ``direction``."""
        b = start
        lead_done = (
            (b[0] - origin[0]) * direction[0] + (b[1] - origin[1]) * direction[1] + (b[2] - origin[2]) * direction[2]
        )
        self._st.move = Line(direction, direction, aim, origin, stop, v, stop + 5.0, lead_done)

    def _make_action(self, cmd: Vec, requests: tuple[Request, ...]) -> Action:
        st = self._st
        a = st.axis
        # Plain Python floats (the same doubles): numpy scalars here would make the device's pen axis, and from
        # it every tick of the controller's force law, numpy-scalar arithmetic, several times slower.
        return Action(
            {
                "x_mm": float(cmd[0]),
                "y_mm": float(cmd[1]),
                "z_mm": float(cmd[2]),
                "dir_x": float(a[0]),
                "dir_y": float(a[1]),
                "dir_z": float(a[2]),
                "button": float(st.button),
            },
            requests,
        )

    def _command(self, percept: Mapping[str, Any]) -> Vec:
        """Advance the reference, then turn the wanted (believed) tip into a hand set-point."""
        st, p = self._st, self.p
        mv = st.move
        dt = st.dt
        z = st.noise()
        if mv is not None and st.button >= 0.5:
            if isinstance(mv, MinJerk):
                mv.elapsed += dt
                s = min(1.0, mv.elapsed / mv.T)
                w = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)
                a, b = mv.a, mv.b
                st.ref = (a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]), a[2] + w * (b[2] - a[2]))
            else:
                # constant speed with a slow fluctuation (signal-dependent motor noise)
                k = dt / 0.5
                st.speed_dev += -k * st.speed_dev + p.speed_noise * math.sqrt(2 * k) * z[6]
                step = mv.v * max(0.2, 1.0 + st.speed_dev) * dt
                r = st.ref
                aim = mv.aim
                if aim is not None:
                    d = (aim[0] - r[0], aim[1] - r[1], aim[2] - r[2])
                    n = _norm(d)
                    if n > 2.0:  # close to the aim point the direction is kept
                        mv.dir = (d[0] / n, d[1] / n, d[2] / n)
                u = mv.dir
                st.ref = (r[0] + step * u[0], r[1] + step * u[1], r[2] + step * u[2])
                mv.ref_s += step
        # lateral wobble (Ornstein–Uhlenbeck), stronger with a noisier hand and, advancing faster than its own
        # insertion pace, in proportion to the speed (signal-dependent motor noise, Harris & Wolpert 1998)
        k = dt / p.motor_tau_s
        sd = p.motor_noise_mm * math.sqrt(2 * k)
        if isinstance(mv, Line) and st.button >= 0.5 and mv.v > st.v_ins:
            sd *= mv.v / st.v_ins
        wb = st.wobble
        for i in range(3):
            wb[i] += -k * wb[i] + sd * z[i]
        # wanted believed tip → set-point: undo the (unknown to it) position-sense error and correction
        r, b, c = st.ref, st.sense.beta, st.sense.corr
        cmd = (r[0] - c[0] - b[0] + wb[0], r[1] - c[1] - b[1] + wb[1], r[2] - c[2] - b[2] + wb[2])
        st.last_cmd = cmd
        return cmd

    # ------------------------------------------------------------------ questionnaires
    def answer(self, item: Mapping[str, Any], rng: np.random.Generator) -> int:
        """A Likert code judged from the session's completed trials (:func:`~.needle_questionnaire.judge_item`).

        The trials are the engine's stored record (``item["history"]``), so an interrupted and resumed session
        answers as an uninterrupted one; its own memory (:attr:`history`) serves only when the item carries no
        record (a bare trial loop).
        """
        record = item.get("history")
        return judge_item(item, record if record is not None else self.history, rng)
