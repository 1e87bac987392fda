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
* **Probes the guidance** (``probe_mm`` > 0): in a scenario's first trial, lined up over the incision, it pushes
  its hand sideways and back, slowly, as people judge compliance by pressing (Lederman & Klatzky 1987); a steady
  hand would otherwise stay inside the guidance's tolerance and never learn that a stiff channel holds it. It
  judges the channel's stiffness (force over sideways travel) only there and in tissue, never while reaching at
  speed, where the channel's damper would push back whatever the stiffness.
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

Code map: :class:`VirtualNeedleOperator` here holds the session-level memory, the tick, one handler per
:class:`~studyctl.participants.needle_trial.Phase` (``_step``) and the transitions between phases; what it
does with images and forces, and what it learns to trust, is the
:class:`~studyctl.participants.needle_senses.OperatorSenses` mixin; how it moves is
:mod:`~studyctl.participants.needle_motor`; the trial state and movement records are in
:mod:`~studyctl.participants.needle_trial`; raw sensing in :mod:`~studyctl.participants.needle_perception`;
parameters in :mod:`~studyctl.participants.needle_params`; questionnaire answers in
:mod:`~studyctl.participants.needle_questionnaire`.

Questionnaire answers are judged from the session's stored trial record the engine passes with each item
(durations, scans, timeouts, each scenario's view), never from memory that a resumed process would lack.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from studyctl.participants.needle_motor import command, make_action, start_line, start_reach
from studyctl.participants.needle_params import DEFAULTS, PARAMS, OperatorParams
from studyctl.participants.needle_perception import PositionSense, feel_force
from studyctl.participants.needle_questionnaire import judge_item
from studyctl.participants.needle_senses import OperatorSenses
from studyctl.participants.needle_trial import Line, MinJerk, Phase, TrialState
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo

__all__ = ["DEFAULTS", "PARAMS", "OperatorParams", "Phase", "VirtualNeedleOperator"]

PROBE_S = 1.2  # CHOSEN: each leg of the sideways probe (s); peak speed 1.9 x probe_mm / PROBE_S
# CHOSEN: after a scan that did not show the tip (above the liver, outside the slices' field), the hand moves this
# far before it asks for another position check: the same view again would show the same nothing
BLIND_MOVE_MM = 5.0
class VirtualNeedleOperator(OperatorSenses, Participant):
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
        # scenario labels whose channel it has pushed against on purpose (``probe_mm``: once per scenario)
        self.probed: set[str] = set()
        # scenario labels in which it has felt a clear axial cue (``cue_by_feel``; empty otherwise)
        self.clear_cue_in: set[str] = set()
        self.s: TrialState | None = None

    # ------------------------------------------------------------------ session and trial set-up
    def memory(self) -> dict[str, Any]:
        """What it has learnt to trust per scenario, and its own trial record, stored by the engine with each
        finished trial: a session resumed in a new process goes on as the uninterrupted one would."""
        memory = {"trust_cue": dict(self.trust_cue), "trust_guide": dict(self.trust_guide),
                  "wall_k": dict(self.wall_k), "probed": sorted(self.probed),
                  "history": [dict(r) for r in self.history]}
        if self.clear_cue_in:  # only with cue_by_feel: the stored memory of other sessions stays as it was
            memory["clear_cue_in"] = sorted(self.clear_cue_in)
        return memory

    def recall(self, memory: Mapping[str, Any]) -> None:
        self.trust_cue = {str(k): float(v) for k, v in (memory.get("trust_cue") or {}).items()}
        self.trust_guide = {str(k): float(v) for k, v in (memory.get("trust_guide") or {}).items()}
        self.wall_k = {str(k): float(v) for k, v in (memory.get("wall_k") or {}).items()}
        self.probed = {str(k) for k in (memory.get("probed") or [])}
        self.clear_cue_in = {str(k) for k in (memory.get("clear_cue_in") or [])}
        self.history = [dict(r) for r in (memory.get("history") or [])]

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        p = self.p
        # this trial's own pace: within-person variation around the person's speed and reading time
        vary = rng.standard_normal(2)
        speed = p.insert_speed_mm_s * math.exp(p.speed_trial_cv * float(vary[0]))
        # Decisions keep ``decision_hz`` in seconds whatever the loop rate: a whole number of ticks per decision
        # would decide at 125 Hz in a 250 Hz loop (2 ticks) and draw its per-decision noise that much more often.
        ratio = max(1.0, info.rate_hz / p.decision_hz)
        dt = ratio / info.rate_hz  # nominal; each decision's own is set in act()
        realtime = info.visual == "realtime"
        if realtime:
            speed *= p.realtime_speed_gain
        n = 4 * (int(info.time_limit_s / dt) + 16)
        z = rng.standard_normal((n, 8))
        home = p.home
        self.s = TrialState(
            info=info,
            ratio=ratio,
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
        )
        self.s.action = make_action(self._st, home, ())

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
        if st.tick < st.next_tick:
            return st.action
        # decision m falls on tick floor(m · ratio), so the mean interval is exactly 1 / decision_hz (at 1 kHz
        # every 10 ticks; at 250 Hz 2 and 3 ticks in turn) and dt is the time this decision's command is held
        st.decisions += 1
        nxt = max(st.tick + 1, math.floor(st.decisions * st.ratio))
        st.dt = (nxt - st.tick) / st.info.rate_hz
        st.next_tick = nxt
        requests = self._decide(t, percept)
        cmd = command(st, self.p)
        st.action = make_action(self._st, cmd, ())
        if requests:  # requests go out once; the ticks until the next decision repeat only the inputs
            return Action(st.action.inputs, requests)
        return st.action

    def _decide(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        st, p = self._st, self.p
        # position sense drifts with intended movement
        z = st.noise()
        moved = math.dist(st.ref, st.prev_ref)
        st.prev_ref = st.ref
        st.sense.drift(moved, p.proprio_drift, z, believed_per_sqrt_mm=p.believed_drift)
        self._perceive(t, percept)
        if st.realtime and "view" in percept and t - st.last_view_t >= p.visual_period_s:
            st.last_view_t = t
            self._look_live(t, percept["view"], percept)
        if st.pending_views:
            self._act_on_looks(t, percept)
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

    def _scan_can_show_tip(self, percept: Mapping[str, Any]) -> bool:
        """Whether a scan asked for to check where the tip is could show it. After one that did not (the tip still
        above the liver, outside the slices' field), it first moves BLIND_MOVE_MM: asking again at once, a person
        with a large position uncertainty requested 26 identical scans over the incision until the 90 s ran out
        (one EG trial of 180, seed 99, recheck_mm's median 1.2)."""
        st = self._st
        if not st.scans_allowed:
            return False
        if st.blind_at is None:
            return True
        if math.dist(st.sense.felt(percept, st.last_cmd), st.blind_at) < BLIND_MOVE_MM:
            return False
        st.blind_at = None
        return True

    def _read_time(self) -> float:
        """Looking at a scan: planning on the first takes longer; a check while a haptic cue of this scenario
        is trusted is a confirming glance (it knows what it expects to see)."""
        st, p = self._st, self.p
        if st.plan is None:
            return st.read_s + p.plan_read_extra_s
        if self._trusts_cue() or self._trusts_guide():
            return st.read_s * p.confirm_read_ratio
        return st.read_s

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
            # the probe comes back as slowly as it went out (PROBE_S each way), the approach goes on at reach speed
            start_reach(self._st, mv.b, mv.then, self.p.probe_mm / PROBE_S if st.probing else st.v_app)
            return ()
        if mv.elapsed >= mv.T + 0.3:
            st.move = None
            st.probing = False
            if self.p.probe_mm > 0.0 and st.button >= 0.5 and st.info.condition not in self.probed:
                return self._probe(percept)
            if st.sense.sig_lat > self.p.entry_scan_mm and self._scan_can_show_tip(percept):
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
                self._felt_clear_cue()  # with cue_by_feel, a clear one marks this scenario as giving it
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
        if sig_lat > p.recheck_mm and depth < pl.length - 10.0 and self._scan_can_show_tip(percept):
            st.stop_reason = "recheck"
            self._relax(percept)
            return self._scan_then(t, Phase.INSERT)
        if (
            st.stop_reason == "depth"
            and self._trusts_cue()
            and depth >= pl.length - p.margin_mm
            and sig_lat > p.finish_mm
            and not st.line_checked
            and self._scan_can_show_tip(percept)
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
            start_reach(self._st, b, far, st.v_app, then=pl.entry)
            return ()
        if st.next_phase is Phase.INSERT:
            return self._enter_insert(percept)
        return self._judge(t, percept)

    def _probe(self, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        """Lined up over the incision in a scenario's first trial: push the hand ``probe_mm`` sideways and back, to
        feel how firmly the channel holds it (judged by :meth:`_perceive` like any growing lateral push). It presses
        against a lateral push it already feels, into what resists (as one presses a surface along its normal to
        judge its compliance, Lederman & Klatzky 1987); feeling none, in a random direction across the pen."""
        st = self._st
        self.probed.add(st.info.condition)
        z, a = st.noise(), st.axis
        felt = feel_force(percept, a, self.p.force_noise_n, z)
        if felt is not None and felt.radial_n > self.p.radial_threshold_n:
            side = (-felt.radial[0], -felt.radial[1], -felt.radial[2])  # the push points back to the line
        else:
            along = z[0] * a[0] + z[1] * a[1] + z[2] * a[2]
            side = (z[0] - along * a[0], z[1] - along * a[1], z[2] - along * a[2])
        n = math.sqrt(side[0] ** 2 + side[1] ** 2 + side[2] ** 2) or 1.0
        r, d = st.ref, self.p.probe_mm / n
        st.probing = True
        st.felt_radial_s = 0.0  # the force rise is judged over this push's own travel, from where it starts
        # slowly (PROBE_S each way): pushed fast, the channel's damper would push back whatever its stiffness
        start_reach(self._st, r, (r[0] + d * side[0], r[1] + d * side[1], r[2] + d * side[2]),
                    self.p.probe_mm / PROBE_S, then=r)
        return ()

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
        if trust and not st.realtime and p.cue_reach >= 0.5:
            # the trusted cue will mark the stop (``cue_reach``): at its reach pace until margin_mm short of the planned
            # depth, where _on_insert slows it to its own pace to feel for the tumour
            speed = max(speed, st.v_app)
        start_line(self._st, b, u, pl.marker, stop, speed, aim=aim)
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
        # a cue felt on the leg just ended but too late to stop on (``cue_learn_late``): the scan judges it as well
        late = seen and st.stop_reason != "cue" and st.cue.felt and p.cue_learn_late >= 0.5
        if (st.stop_reason == "cue" and (seen or learn)) or late:  # was the felt cue the tumour? learn from it
            self._learn_from_cue(miss <= 2.5 * p.accept_mm)
        # after each correction it grows more lenient: a looser placement is accepted rather than a fourth try
        if miss <= p.accept_mm * (1.0 + 0.5 * st.corrections):
            return self._begin_finish(percept, t, "in_tumour")
        st.phase = Phase.INSERT
        st.button = 1.0
        st.ref = b
        st.cue.felt = False
        # aim at the centroid, stop there (by belief) and look again
        d = ((tum[0] - b[0]) / miss, (tum[1] - b[1]) / miss, (tum[2] - b[2]) / miss)
        start_line(self._st, b, d, b, miss, st.v_fin)
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

    # ------------------------------------------------------------------ questionnaires
    def answer(self, item: Mapping[str, Any], rng: np.random.Generator) -> int:
        """A Likert code judged from the session's completed trials (:func:`~.needle_questionnaire.judge_item`).

        The trials are the engine's stored record (``item["history"]``), so an interrupted and resumed session
        answers as an uninterrupted one; its own memory (:attr:`history`) serves only when the item carries no
        record (a bare trial loop).
        """
        record = item.get("history")
        return judge_item(item, record if record is not None else self.history, rng)
