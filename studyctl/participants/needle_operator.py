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
* With a **real-time view** it reads the view a few times a second instead and moves faster.

Outcomes (scans, duration, errors) are therefore whatever happens when this behaviour meets the
controller, the device and the scene; no metric is written here. Behaviour parameters (``PARAMS``) are
our choices, stated with their reasons; the per-participant traits are drawn once per session from the
stream the engine hands to :meth:`VirtualNeedleOperator.begin_session` (the same after a resume).

Questionnaire answers are judged from the session's stored trial record the engine passes with each item
(durations, scans, timeouts, each scenario's view), never from memory that a resumed process would lack.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.participants.ct_reader import CTReading, read_ct
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo
from studyctl.plugins.params import Param, validate_params

PARAMS = (
    Param(
        "insert_speed_mm_s",
        10.0,
        0.0,
        source="CHOSEN: steady needle advance (people insert slowly in liver: ~5–20 mm/s)",
    ),
    Param("final_speed_mm_s", 4.0, 0.0, source="CHOSEN: corrections near the target"),
    Param("approach_speed_mm_s", 25.0, 0.0, source="CHOSEN: free-space moves"),
    Param("realtime_speed_gain", 1.15, 0.0, source="CHOSEN: with a live image people move a little faster"),
    Param(
        "guided_speed_gain",
        1.3,
        0.0,
        source="CHOSEN: inside a channel felt to be firm, lateral slips are not feared: faster",
    ),
    Param(
        "cued_speed_gain",
        1.2,
        0.0,
        source="CHOSEN: when the tumour is known to announce itself, overshooting is not feared",
    ),
    Param("trait_sd", 0.15, 0.0, source="CHOSEN: between-person spread (relative) of speed, noise and drift"),
    Param("decision_hz", 100.0, 0.0, source="CHOSEN: motor/perceptual update rate of the operator"),
    Param("plan_read_s", 4.0, 0.0, source="CHOSEN: looking at the first scan and planning"),
    Param("scan_read_s", 3.0, 0.0, source="CHOSEN: looking at a later scan"),
    Param("visual_period_s", 0.25, 0.0, source="CHOSEN: real-time view: how often it is read"),
    Param("proprio_drift", 0.15, 0.0, source="CHOSEN: mm per √mm moved: position-sense drift (per axis)"),
    Param("motor_noise_mm", 0.3, 0.0, source="CHOSEN: lateral wobble of the hand set-point (stationary sd)"),
    Param("motor_tau_s", 0.5, 0.0, source="CHOSEN"),
    Param("speed_noise", 0.15, 0.0, source="CHOSEN: relative speed fluctuation"),
    Param("orientation_sd_deg", 1.5, 0.0, source="CHOSEN"),
    Param("force_threshold_n", 0.12, 0.0, source="CHOSEN: absolute axial force rise that is noticed"),
    Param("force_weber", 0.15, 0.0, source="CHOSEN: relative axial force rise that is noticed"),
    Param("force_noise_n", 0.02, 0.0, source="CHOSEN: perceptual noise on the felt force"),
    Param("radial_threshold_n", 0.08, 0.0, source="CHOSEN: a lateral push this strong is felt as guidance"),
    Param("follow_gain_mm_per_ns", 3.0, 0.0, source="CHOSEN: how readily it yields to a felt guidance force"),
    Param(
        "wall_n",
        0.3,
        0.0,
        source="CHOSEN: a lateral force this strong feels like a firm channel wall, which it learns to trust",
    ),
    Param("reaction_s", 0.18, 0.0, source="CHOSEN"),
    Param("entry_scan_mm", 0.9, 0.0, source="CHOSEN: scan before entering when the lateral uncertainty exceeds this"),
    Param("recheck_mm", 1.6, 0.0, source="CHOSEN: scan during insertion when the lateral uncertainty exceeds this"),
    Param("finish_mm", 0.8, 0.0, source="CHOSEN: finish without a confirming scan only below this uncertainty"),
    Param(
        "accept_mm",
        2.0,
        0.0,
        source="CHOSEN: a tip this close to the centroid touches the 2.5 mm tumour on the image: done",
    ),
    Param(
        "margin_mm",
        6.0,
        0.0,
        source="CHOSEN: stop this far before the believed target to check, unless a cue is trusted",
    ),
    Param(
        "overshoot_mm",
        3.0,
        0.0,
        source="CHOSEN: when trusting a cue, advance at most this far past the believed target",
    ),
    Param("preentry_mm", 8.0, 0.0, source="CHOSEN: where to put the tip above the incision point before entering"),
    Param("home_x_mm", 0.0, None, source="CHOSEN"),
    Param("home_y_mm", 0.0, None, source="CHOSEN"),
    Param("home_z_mm", 38.0, None, source="CHOSEN"),
)
DEFAULTS: dict[str, float] = {p.name: p.default for p in PARAMS}

# phases
_PLAN, _READ, _APPROACH, _INSERT, _HOLD, _FINISH, _DONE, _JUDGE = range(8)


def _norm(v: tuple[float, float, float]) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


class VirtualNeedleOperator(Participant):
    """Virtual participant for seed 001 (entry point ``virtual_needle_operator``); params: :data:`PARAMS`."""

    name = "virtual_needle_operator"
    virtual = True

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        super().__init__(params)
        p = validate_params("participant virtual_needle_operator", params, PARAMS)
        for key in ("insert_speed_mm_s", "final_speed_mm_s", "approach_speed_mm_s", "decision_hz", "motor_tau_s"):
            if p[key] <= 0:
                raise ModelParameterError(f"participant virtual_needle_operator: {key} = {p[key]:g} must be > 0")
        self.p = p
        self.traits: dict[str, float] | None = None
        self.history: list[dict[str, Any]] = []  # what it remembers of its own trials
        self.trust_cue: dict[str, bool] = {}  # per scenario label: has a force cue marked the target?
        self.trust_guide: dict[str, bool] = {}  # per scenario label: has a firm guidance channel been felt?

    # ------------------------------------------------------------------ trial set-up
    def _draw_traits(self, rng: np.random.Generator) -> dict[str, float]:
        sd = self.p["trait_sd"]

        def f() -> float:
            return float(np.exp(rng.normal(0.0, sd)))

        return {"speed": f(), "noise": f(), "drift": f(), "read": f(), "threshold": f()}

    def begin_session(self, rng: np.random.Generator) -> None:
        """The engine hands over the session's person stream at every (re)start: the same traits after a resume."""
        self.traits = self._draw_traits(rng)

    def memory(self) -> dict[str, Any]:
        """What it has learnt to trust per scenario, and its own trial record, stored by the engine with each
        finished trial: a session resumed in a new process goes on as the uninterrupted one would."""
        return {"trust_cue": dict(self.trust_cue), "trust_guide": dict(self.trust_guide),
                "history": [dict(r) for r in self.history]}

    def recall(self, memory: Mapping[str, Any]) -> None:
        self.trust_cue = {str(k): bool(v) for k, v in (memory.get("trust_cue") or {}).items()}
        self.trust_guide = {str(k): bool(v) for k, v in (memory.get("trust_guide") or {}).items()}
        self.history = [dict(r) for r in (memory.get("history") or [])]

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        if self.traits is None:  # run outside a session (a bare trial loop): the first trial's stream
            self.traits = self._draw_traits(rng)
        p, tr = self.p, self.traits
        self.info = info
        self.rng = rng
        self._every = max(1, round(info.rate_hz / p["decision_hz"]))
        self._dt = self._every / info.rate_hz
        self._tick = self._every - 1  # decide on the first call
        self._realtime = info.visual == "realtime"
        self._scans_allowed = info.visual == "on_request"
        gain = p["realtime_speed_gain"] if self._realtime else 1.0
        self._v_ins = p["insert_speed_mm_s"] * tr["speed"] * gain
        self._v_fin = p["final_speed_mm_s"] * tr["speed"] * gain
        self._v_app = p["approach_speed_mm_s"] * tr["speed"] * gain
        n = 4 * (int(info.time_limit_s / self._dt) + 16)
        self._z = rng.standard_normal((n, 8))  # pre-drawn noise: three rows per decision
        self._zi = 0
        home = (p["home_x_mm"], p["home_y_mm"], p["home_z_mm"])
        self._ref = home  # where it wants its (believed) tip
        self._beta = [0.0, 0.0, 0.0]  # proprioceptive error
        self._corr = (0.0, 0.0, 0.0)  # correction learnt from the last image
        self._wobble = [0.0, 0.0, 0.0]
        self._speed_dev = 0.0
        self._last_cmd = home
        self._axis = (0.0, 0.0, -1.0)
        self._button = 1.0
        self._phase = _PLAN
        self._next_phase = _PLAN
        self._busy_until = 0.0
        self._frame: Mapping[str, Any] | None = None
        self._last_view_t = -1e9
        self._plan: dict[str, Any] | None = None
        self._sig_lat = 3.0  # its uncertainty (mm) about where the tip is, lateral and along the path
        self._sig_ax = 3.0
        self._move: dict[str, Any] | None = None
        self._baseline = None
        self._cue_run = 0.0
        self._cue_felt = False
        self._react_until = 0.0
        self._scans = 0
        self._finish_at: float | None = None
        self._stop_reason = ""
        self._felt_radial = 0.0
        self._corrections = 0
        self._prev_ref = home
        self._trial = {
            "condition": info.condition,
            "visual": info.visual,
            "cue": False,
            "wall": False,
            "radial_felt_s": 0.0,
        }
        self._action = self._make_action(home, ())

    # ------------------------------------------------------------------ helpers
    def _make_action(self, cmd: tuple[float, float, float], requests: tuple[Request, ...]) -> Action:
        a = self._axis
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
                "button": float(self._button),
            },
            requests,
        )

    def _noise(self) -> np.ndarray:
        z = self._z[self._zi]
        self._zi = (self._zi + 1) % len(self._z)
        return z

    def _felt_raw(self, percept: Mapping[str, Any]) -> tuple[float, float, float]:
        """Where it feels the handle: the true position plus its drifting position-sense error."""
        b = self._beta
        if "x_mm" in percept:
            return (percept["x_mm"] + b[0], percept["y_mm"] + b[1], percept["z_mm"] + b[2])
        c = self._last_cmd
        return (c[0] + b[0], c[1] + b[1], c[2] + b[2])

    def _belief(self, percept: Mapping[str, Any]) -> tuple[float, float, float]:
        f, c = self._felt_raw(percept), self._corr
        return (f[0] + c[0], f[1] + c[1], f[2] + c[2])

    def _take_image(self, frame: Mapping[str, Any], percept: Mapping[str, Any], t: float) -> CTReading:
        reading = read_ct(frame, self._axis)
        if reading.tip_mm is not None:
            f, old, r = self._felt_raw(percept), self._corr, self._ref
            c = (reading.tip_mm[0] - f[0], reading.tip_mm[1] - f[1], reading.tip_mm[2] - f[2])
            self._corr = c
            # the belief moved, the hand did not: keep the set-point where it is
            self._ref = (r[0] + c[0] - old[0], r[1] + c[1] - old[1], r[2] + c[2] - old[2])
            self._prev_ref = self._ref
            self._sig_lat = self._sig_ax = 0.3
        if self._plan is None and reading.tumour_mm is not None and reading.marker_mm is not None:
            self._make_plan(reading)
        return reading

    def _make_plan(self, reading: CTReading) -> None:
        t, m = reading.tumour_mm, reading.marker_mm
        if t is None or m is None:
            return
        d = (t[0] - m[0], t[1] - m[1], t[2] - m[2])
        length = _norm(d)
        u = (d[0] / length, d[1] / length, d[2] / length)
        # the pen is pointed along the plan with an orientation error
        z = self._noise()
        err = math.radians(self.p["orientation_sd_deg"])
        a = (u[0] + err * z[0], u[1] + err * z[1], u[2] + err * z[2])
        n = _norm(a)
        self._axis = (a[0] / n, a[1] / n, a[2] / n)
        pre = self.p["preentry_mm"]
        self._plan = {
            "tumour": t,
            "marker": m,
            "u": u,
            "length": length,
            "entry": (m[0] - pre * u[0], m[1] - pre * u[1], m[2] - pre * u[2]),
        }

    def _need_plan(self) -> dict[str, Any]:
        if self._plan is None:
            raise RuntimeError("virtual_needle_operator: acting on a plan before a scan produced one")
        return self._plan

    def _depth(self, b: tuple[float, float, float]) -> float:
        """Believed depth of the tip along the planned path, from the marker (mm)."""
        pl = self._need_plan()
        m, u = pl["marker"], pl["u"]
        return (b[0] - m[0]) * u[0] + (b[1] - m[1]) * u[1] + (b[2] - m[2]) * u[2]

    def _start_move(self, t: float, start: tuple[float, ...], goal: tuple[float, ...], speed: float) -> None:
        """A free-space reach: minimum-jerk reference from ``start`` to ``goal``."""
        dist = math.dist(start, goal)
        self._move = {"kind": "minjerk", "t0": t, "T": max(dist / speed, 0.3), "a": tuple(start), "b": tuple(goal)}

    def _start_line(
        self,
        start: tuple[float, ...],
        direction: tuple[float, ...],
        origin: tuple[float, ...],
        stop: float,
        v: float,
        aim: tuple[float, ...] | None = None,
    ) -> None:
        """Advance the reference until the believed tip is ``stop`` mm past ``origin`` along ``direction``.

        With ``aim`` the reference heads for that point (re-aimed at every decision, so an offset seen on
        an image is steered out), else it moves along ``direction``. The reference may lead the believed
        tip (tissue resists, the hand is compliant) by at most 5 mm: beyond that the operator gives up
        this push and stops.
        """
        b = tuple(start)
        lead_done = (
            (b[0] - origin[0]) * direction[0] + (b[1] - origin[1]) * direction[1] + (b[2] - origin[2]) * direction[2]
        )
        self._move = {
            "kind": "line",
            "dir": tuple(direction),
            "axis": tuple(direction),
            "aim": None if aim is None else tuple(aim),
            "origin": tuple(origin),
            "stop": stop,
            "v": v,
            "max_ref": stop + 5.0,
            "ref_s": lead_done,
        }

    def _scan_then(self, t: float, next_phase: int) -> tuple[Request, ...]:
        """Hold still and request a scan (or just pause to look in real-time conditions)."""
        self._button = 0.0
        self._phase = _READ
        self._next_phase = next_phase
        if self._scans_allowed:
            self._scans += 1
            self._frame = None
            self._busy_until = math.inf  # until the frame arrives
            return (Request("scan"),)
        self._busy_until = t + 0.5 * self.p["scan_read_s"] * self.traits["read"]  # type: ignore[index]
        return ()

    # ------------------------------------------------------------------ the tick
    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        if "scan" in percept and percept["scan"] is not None:
            self._frame = percept["scan"]
            if self._busy_until == math.inf:
                read = self.p["plan_read_s"] if self._plan is None else self.p["scan_read_s"]
                self._busy_until = t + read * self.traits["read"]  # type: ignore[index]
        self._tick += 1
        if self._tick < self._every:
            return self._action
        self._tick = 0
        requests = self._decide(t, percept)
        cmd = self._command(percept)
        self._action = self._make_action(cmd, ())
        if requests:  # requests go out once; the ticks until the next decision repeat only the inputs
            return Action(self._action.inputs, requests)
        return self._action

    def _perceive(self, t: float, percept: Mapping[str, Any]) -> None:
        """Forces on the hand: axial cue detection and lateral guidance following."""
        if "fx_n" not in percept:
            return
        z = self._noise()
        sn = self.p["force_noise_n"]
        fx, fy, fz = percept["fx_n"] + sn * z[3], percept["fy_n"] + sn * z[4], percept["fz_n"] + sn * z[5]
        a = self._axis
        f_ax = -(fx * a[0] + fy * a[1] + fz * a[2])  # resistance felt along the needle
        rx, ry, rz = fx + f_ax * a[0], fy + f_ax * a[1], fz + f_ax * a[2]
        f_rad = math.sqrt(rx * rx + ry * ry + rz * rz)
        th = self.traits["threshold"]  # type: ignore[index]
        if self._button >= 0.5 and f_rad > self.p["radial_threshold_n"] * th:
            # a felt lateral push: yield to it, and trust that it keeps the tip near the path
            g = self.p["follow_gain_mm_per_ns"] * self._dt
            r = self._ref
            self._ref = (r[0] + g * rx, r[1] + g * ry, r[2] + g * rz)
            self._trial["radial_felt_s"] += self._dt
            self._felt_radial += self._dt
            if self._felt_radial > 0.2:
                self._sig_lat = min(self._sig_lat, self.p["finish_mm"])
            if f_rad > self.p["wall_n"] * th and self._phase == _INSERT:  # the channel, felt in tissue
                self.trust_guide[self.info.condition] = True
                self._trial["wall"] = True
        else:
            self._felt_radial = 0.0
        if self._button >= 0.5 and self.trust_guide.get(self.info.condition, False):
            # inside a channel it has felt to be firm, it takes the tip to be on the path laterally
            self._sig_lat = min(self._sig_lat, 0.9 * self.p["finish_mm"])
        # axial cue: a rise above the running baseline while advancing deep in the liver
        mv = self._move
        if self._phase == _INSERT and self._plan is not None and self._button >= 0.5 and mv is not None:
            mv["moving_s"] = mv.get("moving_s", 0.0) + self._dt
            depth = self._depth(self._belief(percept))
            steady = mv["moving_s"] >= 0.5 and f_ax > 0.0  # sliding in, not starting, stopping or pulling
            if self._baseline is None or depth < 0.5 * self._plan["length"]:
                # learn what liver resistance feels like on the way in; it is kept for the whole trial
                if steady:
                    b0 = self._baseline
                    self._baseline = f_ax if b0 is None else b0 + 0.1 * (f_ax - b0)
                self._cue_run = 0.0
                return
            rise = f_ax - self._baseline
            need = max(self.p["force_threshold_n"] * th, self.p["force_weber"] * th * abs(self._baseline))
            if mv["moving_s"] < 0.3:  # the start of every push feels stiffer (stiction): expect ~30 % more
                need += 0.3 * abs(self._baseline)
            if rise > need:
                self._cue_run += self._dt
                if self._cue_run >= 0.05 and not self._cue_felt:
                    self._cue_felt = True
                    self._trial["cue"] = True
                    self._react_until = t + self.p["reaction_s"]
            else:
                self._cue_run = 0.0
                if steady:
                    self._baseline += (self._dt / 0.3) * (f_ax - self._baseline)

    def _decide(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        p = self.p
        # position sense drifts with movement
        z = self._noise()
        moved = math.dist(self._ref, self._prev_ref)  # intended movement drives the drift
        self._prev_ref = self._ref
        if moved > 0.0:
            s = p["proprio_drift"] * self.traits["drift"] * math.sqrt(moved)  # type: ignore[index]
            b = self._beta
            b[0] += s * z[0]
            b[1] += s * z[1]
            b[2] += s * z[2]
            grow = (p["proprio_drift"] * self.traits["drift"]) ** 2 * moved  # type: ignore[index]
            self._sig_lat = math.sqrt(self._sig_lat**2 + grow)
            self._sig_ax = math.sqrt(self._sig_ax**2 + grow)
        self._perceive(t, percept)
        if self._realtime and "view" in percept and t - self._last_view_t >= p["visual_period_s"]:
            self._last_view_t = t
            self._take_image(percept["view"], percept, t)
        if self._finish_at is None and t > self.info.time_limit_s - 3.0 and self._phase not in (_FINISH, _DONE):
            return self._begin_finish(t, percept, "time")
        phase = self._phase
        if phase == _PLAN:
            if self._realtime:
                if self._plan is not None:
                    read = p["plan_read_s"] * self.traits["read"]  # type: ignore[index]
                    self._phase, self._busy_until, self._next_phase = _READ, t + read, _APPROACH
                return ()
            return self._scan_then(t, _APPROACH)
        if phase == _READ:
            if t < self._busy_until:
                return ()
            if self._frame is not None:
                self._take_image(self._frame, percept, t)
                self._frame = None
            if self._plan is None:
                return self._scan_then(t, self._next_phase)
            return self._after_read(t, percept)
        if phase == _APPROACH:
            mv = self._move
            if mv is not None and "then" in mv and mv.get("elapsed", 0.0) >= mv["T"]:
                self._start_move(t, mv["b"], mv["then"], self._v_app)
                return ()
            if mv is not None and mv.get("elapsed", 0.0) >= mv["T"] + 0.3:
                self._move = None
                if self._scans_allowed and self._sig_lat > p["entry_scan_mm"]:
                    return self._scan_then(t, _INSERT)
                return self._enter_insert(t, percept)
            return ()
        if phase == _INSERT:
            return self._insert_step(t, percept)
        if phase == _HOLD:
            if t < self._busy_until:
                return ()
            return self._after_hold(t, percept)
        if phase == _FINISH:
            if t >= self._busy_until:
                self._phase = _DONE
                self._remember(t)
                return (Request("finish"),)
            return ()
        return ()

    def _after_read(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        """Act on a fresh image: start the approach, enter, or judge where the tip is."""
        nxt = self._next_phase
        b = self._belief(percept)
        self._button = 1.0
        if nxt == _APPROACH:
            # reach the pre-entry point from further out along the path, so the tip never cuts the liver
            pl = self._need_plan()
            self._phase = _APPROACH
            self._ref = b
            far = tuple(pl["entry"][i] - 20.0 * pl["u"][i] for i in range(3))
            self._start_move(t, b, far, self._v_app)
            self._move["then"] = pl["entry"]  # type: ignore[index]
            return ()
        if nxt == _INSERT:
            return self._enter_insert(t, percept)
        return self._judge(t, percept)

    def _enter_insert(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        pl = self._need_plan()
        self._phase = _INSERT
        self._button = 1.0
        b = self._belief(percept)
        self._ref = b
        trust = self.trust_cue.get(self.info.condition, False)
        if self._realtime:
            stop = pl["length"]
        elif trust:
            stop = pl["length"] + self.p["overshoot_mm"]
        else:
            stop = pl["length"] - self.p["margin_mm"]
        extra = stop - pl["length"] if stop > pl["length"] else 0.0
        u, tum = pl["u"], pl["tumour"]
        aim = (tum[0] + extra * u[0], tum[1] + extra * u[1], tum[2] + extra * u[2])
        speed = self._v_ins
        if self.trust_guide.get(self.info.condition, False):
            speed *= self.p["guided_speed_gain"]
        if trust:
            speed *= self.p["cued_speed_gain"]
        self._start_line(b, u, pl["marker"], stop, speed, aim=aim)
        self._stop_reason = "depth"
        return ()

    def _insert_step(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        pl = self._need_plan()
        if self._cue_felt and self._react_until and t >= self._react_until:
            # a force cue: stop, hold, relax the push
            self._react_until = 0.0
            return self._stop(t, percept, "cue")
        mv = self._move
        if mv is None:
            return self._stop(t, percept, "blocked")
        b = self._belief(percept)
        o, d = mv["origin"], mv["axis"]
        done = (b[0] - o[0]) * d[0] + (b[1] - o[1]) * d[1] + (b[2] - o[2]) * d[2]
        if done >= mv["stop"]:
            return self._stop(t, percept, self._stop_reason if self._stop_reason == "correct" else "depth")
        if mv["ref_s"] >= mv["max_ref"]:
            return self._stop(t, percept, "blocked")
        depth = self._depth(b)
        if self._scans_allowed and self._sig_lat > self.p["recheck_mm"] and depth < pl["length"] - 10.0:
            self._stop_reason = "recheck"
            self._relax(percept)
            return self._scan_then(t, _INSERT)
        if (
            self._scans_allowed
            and self._stop_reason == "depth"
            and self.trust_cue.get(self.info.condition, False)
            and depth >= pl["length"] - self.p["margin_mm"]
            and self._sig_lat > self.p["finish_mm"]
        ):
            # going by feel for the depth, but the tip must be on line to meet the small tumour: check once
            self._stop_reason = "recheck"
            self._relax(percept)
            return self._scan_then(t, _INSERT)
        if self._realtime and math.dist(b, pl["tumour"]) <= 0.5 * self.p["accept_mm"]:
            return self._stop(t, percept, "seen")
        return ()

    def _relax(self, percept: Mapping[str, Any]) -> None:
        """Stop pushing: the wanted position becomes where it feels the tip is."""
        self._move = None
        self._ref = self._belief(percept)

    def _stop(self, t: float, percept: Mapping[str, Any], reason: str) -> tuple[Request, ...]:
        self._relax(percept)
        self._button = 0.0
        self._stop_reason = reason
        self._phase = _HOLD
        self._busy_until = t + 0.3
        return ()

    def _after_hold(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        if self._stop_reason == "cue":
            trust = self.trust_cue.get(self.info.condition, False)
            if trust and self._sig_lat <= self.p["finish_mm"]:
                return self._begin_finish(t, percept, "cue")
        if self._realtime:
            return self._judge(t, percept)
        return self._scan_then(t, _JUDGE)

    def _judge(self, t: float, percept: Mapping[str, Any]) -> tuple[Request, ...]:
        """Is the tip in the tumour? If not, correct towards it (advancing or withdrawing slowly)."""
        pl = self._need_plan()
        b = self._belief(percept)
        tum = pl["tumour"]
        miss = math.dist(b, tum)
        if self._stop_reason == "cue" and miss <= 2.5 * self.p["accept_mm"]:
            self.trust_cue[self.info.condition] = True
        if miss <= self.p["accept_mm"]:
            return self._begin_finish(t, percept, "in_tumour")
        self._phase = _INSERT
        self._button = 1.0
        self._ref = b
        self._cue_felt = False
        # aim at the centroid, stop there (by belief) and look again
        d = ((tum[0] - b[0]) / miss, (tum[1] - b[1]) / miss, (tum[2] - b[2]) / miss)
        self._start_line(b, d, b, miss, self._v_fin)
        self._stop_reason = "correct"
        self._corrections += 1
        return ()

    def _begin_finish(self, t: float, percept: Mapping[str, Any], why: str) -> tuple[Request, ...]:
        self._relax(percept)
        self._button = 0.0
        self._phase = _FINISH
        self._busy_until = t + self.p["reaction_s"] + 0.3
        self._trial["finish_reason"] = why
        return ()

    def _remember(self, t: float) -> None:
        self._trial.update(duration_s=t, scans=self._scans, corrections=self._corrections)
        self.history.append(dict(self._trial))

    # ------------------------------------------------------------------ motor output
    def _command(self, percept: Mapping[str, Any]) -> tuple[float, float, float]:
        """Advance the reference, then turn the wanted (believed) tip into a hand set-point."""
        p, tr = self.p, self.traits
        mv = self._move
        dt = self._dt
        z = self._noise()
        if mv is not None and self._button >= 0.5:
            if mv["kind"] == "minjerk":
                mv["elapsed"] = mv.get("elapsed", 0.0) + dt
                s = min(1.0, mv["elapsed"] / mv["T"])
                w = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)
                a, b = mv["a"], mv["b"]
                self._ref = (a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]), a[2] + w * (b[2] - a[2]))
            else:
                # constant speed with a slow fluctuation (signal-dependent motor noise)
                k = dt / 0.5
                self._speed_dev += -k * self._speed_dev + p["speed_noise"] * math.sqrt(2 * k) * z[6]
                step = mv["v"] * max(0.2, 1.0 + self._speed_dev) * dt
                r = self._ref
                aim = mv["aim"]
                if aim is not None:
                    d = (aim[0] - r[0], aim[1] - r[1], aim[2] - r[2])
                    n = _norm(d)
                    if n > 2.0:  # close to the aim point the direction is kept
                        mv["dir"] = (d[0] / n, d[1] / n, d[2] / n)
                u = mv["dir"]
                self._ref = (r[0] + step * u[0], r[1] + step * u[1], r[2] + step * u[2])
                mv["ref_s"] += step
        # lateral wobble (Ornstein–Uhlenbeck), stronger with a noisier hand
        k = dt / p["motor_tau_s"]
        sd = p["motor_noise_mm"] * tr["noise"] * math.sqrt(2 * k)  # type: ignore[index]
        wb = self._wobble
        for i in range(3):
            wb[i] += -k * wb[i] + sd * z[i]
        # wanted believed tip → set-point: undo the (unknown to it) position-sense error and correction
        r, b, c = self._ref, self._beta, self._corr
        cmd = (r[0] - c[0] - b[0] + wb[0], r[1] - c[1] - b[1] + wb[1], r[2] - c[2] - b[2] + wb[2])
        self._last_cmd = cmd
        return cmd

    # ------------------------------------------------------------------ questionnaires
    def answer(self, item: Mapping[str, Any], rng: np.random.Generator) -> int:
        """A Likert code judged from the completed trials of the session (faster, fewer scans, fewer timeouts).

        The trials are the engine's stored record (``item["history"]``: condition, its view, duration, scans,
        how each ended, in plan order), so an interrupted and resumed session answers as an uninterrupted one;
        its own memory (:attr:`history`) serves only when the item carries no record (a bare trial loop).
        """
        codes = list(item.get("codes") or [1, 2, 3, 4, 5])
        lo, hi = min(codes), max(codes)
        mid = (lo + hi) / 2.0
        half = (hi - lo) / 2.0
        record = item.get("history")
        rows = [dict(r) for r in (record if record is not None else self.history)]
        cond = item.get("condition")
        key = f"{item.get('id', '')} {item.get('text', '')}".lower()
        mine = [r for r in rows if r.get("condition") == cond] if cond else []
        first = rows[0].get("condition") if rows else None
        base = [r for r in rows if r.get("condition") == first]

        def mean(sel: list[dict[str, Any]], k: str) -> float:
            vals = [float(r[k]) for r in sel if r.get(k) is not None]
            return sum(vals) / len(vals) if vals else math.nan

        def faster(sel: list[dict[str, Any]]) -> float:
            d0, d1 = mean(base, "duration_s"), mean(sel, "duration_s")
            return (d0 - d1) / d0 if sel and base and d0 > 0 else 0.0

        def fewer_scans(sel: list[dict[str, Any]]) -> float:
            s0, s1 = mean(base, "scans"), mean(sel, "scans")
            return (s0 - s1) / s0 if sel and base and s0 > 0 else 0.0

        def gain(sel: list[dict[str, Any]]) -> float:
            """Relative improvement over the first scenario (time counts twice as much as scans)."""
            if not sel or not base:
                return 0.0
            if mean(base, "scans") > 0:
                return (2 * faster(sel) + fewer_scans(sel)) / 3
            return faster(sel)

        def timeouts(sel: list[dict[str, Any]]) -> float:
            """Share of trials stopped by the time limit (the target not reached in time)."""
            late = sum(1 for r in sel if r.get("timed_out") or r.get("ended_by") == "time_limit")
            return late / len(sel) if sel else 0.0

        # the scenarios with enhanced haptics: after the first (baseline) one, without the real-time image
        haptic = [r for r in rows if r.get("visual") != "realtime" and r.get("condition") != first]
        if "baseline" in key or "improv" in key:
            score = mid + half * math.tanh(3.0 * gain(mine))
        elif "navigat" in key or "easy" in key and "haptic" not in key:
            score = mid + half * math.tanh(3.0 * faster(mine) - 1.5 * timeouts(mine))
        elif "confiden" in key:
            score = mid + half * math.tanh(1.5 * gain(mine) + 1.5 * fewer_scans(mine) - 1.5 * timeouts(mine))
        elif "equal" in key:
            rt = [r for r in rows if r.get("visual") == "realtime"]
            score = hi - 4 * half * abs(gain(rt) - gain(haptic)) if rt and haptic else mid
        elif "haptic" in key or "easier" in key:
            score = mid + half * math.tanh(3.0 * gain(haptic))
        elif "learn" in key:
            half_n = len(rows) // 2
            early, late = rows[:half_n], rows[half_n:]
            d0, d1 = mean(early, "duration_s"), mean(late, "duration_s")
            score = mid + half * (math.tanh(3.0 * (d0 - d1) / d0) if early and late and d0 > 0 else 0.0)
        else:
            score = mid
        score += float(rng.normal(0.0, 0.6))
        return int(min(hi, max(lo, round(score))))
