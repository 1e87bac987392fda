"""``studyctl bench needle``: the 1 kHz needle loop's cost, a virtual trial's speed, real-time pacing.

Figures
-------
step_us_median, step_us_p99
    One servo tick: the needle controller's step (tissue model, guidance, frame rotation) plus the safety
    layer's filter, timed tick by tick over a scripted ESG insertion through capsule, liver and tumour.
    Peer (same run): the same tick with the geometry done on NumPy 3-vectors (what "plain floats" avoids).
trial_realtime_factor
    Simulated seconds per CPU second of one 90 s virtual trial (BL, virtual operator, simulated device,
    the full :func:`~studyctl.engine.trial_loop.run_trial` with safety layer and a sample sink). The
    operator's finish request is withheld so that the trial runs its full 90 s.
period_jitter_us_p99
    p99 of |period − 1 ms| over 10 s of real-time pacing (RealClock) of the needle loop in its own servo
    process while this process runs a busy "UI/logging" thread. Peer: the same loop in this process next to
    the same thread (sharing the interpreter lock).
"""

from __future__ import annotations

import functools
import math
import os
import threading
import time
from typing import Any

import numpy as np

from studyctl.bench import BenchResult, busy_python
from studyctl.controllers.needle import NeedleHybridController
from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.errors import BenchmarkError
from studyctl.participants.needle_operator import VirtualNeedleOperator
from studyctl.plugins.interfaces import Action, IdleParticipant, Observation, Participant, TrialInfo
from studyctl.plugins.safety import SafetyLayer
from studyctl.protocol import load_protocol, resolve_protocol
from studyctl.scenes.needle_liver import NeedleLiverScene


def _scene(needs: frozenset[str] = frozenset({"layers"})) -> NeedleLiverScene:
    return NeedleLiverScene.build({}, {"sites": {"tumour": 1}}, needs, np.random.default_rng(0))


def _insertion_observations(scene: NeedleLiverScene, n: int) -> list[Observation]:
    """A scripted insertion at 15 mm/s from 20 mm outside to 3 mm past the tumour, 0.8 mm off the path."""
    g = scene.geometry()
    a, u = np.array(g.incision_mm), np.array(g.planned_direction)
    off = np.cross(u, [1.0, 0.0, 0.0])
    off *= 1.6 / np.linalg.norm(off)  # beyond the 1 mm tolerance: the guidance spring works too
    s_end = g.planned_length_mm + 3.0
    obs = []
    for k in range(n):
        s = -20.0 + (s_end + 20.0) * k / max(n - 1, 1)
        p = a + s * u + off * math.sin(k / 300.0)
        v = 15.0 * u
        obs.append(
            Observation(
                k * 1e-3,
                {
                    "x_mm": float(p[0]),
                    "y_mm": float(p[1]),
                    "z_mm": float(p[2]),
                    "vx_mm_s": float(v[0]),
                    "vy_mm_s": float(v[1]),
                    "vz_mm_s": float(v[2]),
                    "dir_x": float(u[0]),
                    "dir_y": float(u[1]),
                    "dir_z": float(u[2]),
                    "button": 1.0,
                    "fault": 0.0,
                },
            )
        )
    return obs


def _numpy_tick(o: Observation, a: np.ndarray, d: np.ndarray, kp: float, kd: float, tol: float) -> np.ndarray:
    """Peer: body frame, radial guidance and rotation to the device frame on NumPy 3-vectors."""
    v = o.values
    p = np.array([v["x_mm"], v["y_mm"], v["z_mm"]])
    vel = np.array([v["vx_mm_s"], v["vy_mm_s"], v["vz_mm_s"]])
    u = np.array([v["dir_x"], v["dir_y"], v["dir_z"]])
    u = u / np.linalg.norm(u)
    y = np.cross([0.0, 0.0, 1.0], u)
    y /= np.linalg.norm(y)
    z = np.cross(u, y)
    w = p - a
    e = (w @ d) * d - w
    e_b = np.array([e @ y, e @ z])
    r = np.linalg.norm(e_b)
    f_b = np.zeros(2)
    if r > tol:
        f_b = kp * 1e-3 * (r - tol) * e_b / r - kd * 1e-3 * np.array([vel @ y, vel @ z])
    rot = np.column_stack([u, y, z])
    return rot @ np.array([0.0, f_b[0], f_b[1]])


@functools.cache
def _protocol():  # noqa: ANN202
    return load_protocol(resolve_protocol("needle_insertion"))


def _scenario(condition: str) -> dict[str, Any]:
    """A scenario's controller params, from the shipped protocol (where Table 1 is written)."""
    return dict(_protocol().condition(condition).params)


def _time_ticks(n: int) -> tuple[np.ndarray, np.ndarray]:
    scene = _scene()
    obs = _insertion_observations(scene, n)
    ctrl = NeedleHybridController(_scenario("ESG"), scene)
    device = SimulatedForceDevice({"device_class": "omega6"}, scene)
    safety = SafetyLayer(device.limits, period_s=1e-3)
    clock = time.perf_counter
    ours = np.empty(n)
    for i, o in enumerate(obs):
        t0 = clock()
        safety.filter(ctrl.step(o), o.t, o)
        ours[i] = clock() - t0
    g = scene.geometry()
    a, d = np.array(g.incision_mm), np.array(g.planned_direction)
    safety = SafetyLayer(device.limits, period_s=1e-3)
    peer = np.empty(n)
    for i, o in enumerate(obs):
        t0 = clock()
        f = _numpy_tick(o, a, d, 1000.0, 50.0, 1.0)
        safety.filter({"fx_n": float(f[0]), "fy_n": float(f[1]), "fz_n": float(f[2])}, o.t, o)
        peer[i] = clock() - t0
    return ours * 1e6, peer * 1e6


class _NoFinish(Participant):
    """Wraps a participant and withholds its finish request, so the trial runs to its time limit."""

    name = "no_finish"

    def __init__(self, inner: Participant) -> None:
        super().__init__({})
        self.inner = inner

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        self.inner.begin_trial(info, rng)

    def act(self, t: float, percept: Any) -> Action:
        a = self.inner.act(t, percept)
        if a.requests and any(r.kind == "finish" for r in a.requests):
            return Action(a.inputs, tuple(r for r in a.requests if r.kind != "finish"))
        return a


def _virtual_trial(limit_s: float) -> tuple[float, float, int]:
    scene = _scene(frozenset({"layers", "view"}))
    ctrl = NeedleHybridController(_scenario("BL"), scene)
    device = SimulatedForceDevice({"device_class": "omega6"}, scene)
    device.open()
    info = TrialInfo("BL", limit_s, 1000.0, "on_request")
    stored: list[Any] = []
    participant = _NoFinish(VirtualNeedleOperator({}))
    c0, w0 = time.process_time(), time.perf_counter()
    out = run_trial(
        info=info,
        controller=ctrl,
        device=device,
        participant=participant,
        clock=SimulatedClock(),
        rng=np.random.default_rng(1),
        on_sample=lambda t, s: stored.append(s),
        view=scene.view,
    )
    return time.process_time() - c0, time.perf_counter() - w0, out.ticks


def _jitter_in_process(seconds: float) -> dict[str, float]:
    from studyctl.engine.realtime import TimedClock  # noqa: PLC0415

    scene = _scene()
    ctrl = NeedleHybridController(_scenario("ESG"), scene)
    device = SimulatedForceDevice({"device_class": "omega6"}, scene)
    device.open()
    clock = TimedClock(capacity=int(seconds * 1000) + 16)
    run_trial(
        info=TrialInfo("ESG", seconds, 1000.0, "none"),
        controller=ctrl,
        device=device,
        participant=IdleParticipant(),
        clock=clock,
        rng=np.random.default_rng(2),
        on_sample=lambda t, s: None,
    )
    return clock.timing(1e-3).as_dict()


def _jitter_servo(seconds: float) -> dict[str, float]:
    from studyctl.engine.servo import ServoSpec, run_trial_in_servo_process  # noqa: PLC0415

    spec = ServoSpec(
        info=TrialInfo("ESG", seconds, 1000.0, "none"),
        device="sim_force3d",
        device_params={"device_class": "omega6"},
        controller="needle_hybrid",
        controller_params=_scenario("ESG"),
        scene="needle_liver",
        scene_placement={"sites": {"tumour": 1}},
        scene_needs=frozenset({"layers"}),
        seed=2,
    )
    result = run_trial_in_servo_process(spec, on_sample=lambda t, s: None)
    if result.timing is None:
        raise BenchmarkError("the servo process reported no timing")
    return result.timing.as_dict()


def run(quick: bool = False) -> BenchResult:
    """Measure the figures described in the module docstring (``quick``: fewer ticks, shorter runs)."""
    n = 3000 if quick else 30000
    ours, peer = _time_ticks(n)
    limit = 10.0 if quick else 90.0
    cpu_s, wall_s, ticks = _virtual_trial(limit)
    jitter_s = 1.0 if quick else 10.0
    stop = threading.Event()
    ui = threading.Thread(target=busy_python, args=(stop,), daemon=True)
    ui.start()
    try:
        servo = _jitter_servo(jitter_s)
        inproc = _jitter_in_process(jitter_s)
    finally:
        stop.set()
        ui.join()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    figures = {
        "step_us_median": float(np.median(ours)),
        "step_us_p99": float(np.percentile(ours, 99)),
        "trial_realtime_factor": limit / cpu_s,
        "period_jitter_us_p99": servo["period_jitter_us_p99"],
    }
    peers = {
        "step_us_median": float(np.median(peer)),
        "step_us_p99": float(np.percentile(peer, 99)),
        "period_jitter_us_p99": inproc["period_jitter_us_p99"],
    }
    cols = ("ticks", "late_us_p50", "late_us_p99", "period_jitter_us_p50", "period_jitter_us_p99", "overruns")
    rows = [
        {"loop": "servo process", **{k: round(float(servo[k]), 1) for k in cols}},
        {"loop": "in-process (peer)", **{k: round(float(inproc[k]), 1) for k in cols}},
    ]
    notes = [
        f"step: {n} ticks of a scripted ESG insertion (controller step + safety filter); peer: NumPy 3-vector tick",
        f"virtual trial: {limit:g} s BL trial, {ticks} ticks, {cpu_s:.2f} s CPU, {wall_s:.2f} s wall "
        f"(wall factor {limit / wall_s:.1f}x); realtime factor uses CPU time of this process",
        f"jitter: {jitter_s:g} s at 1 kHz with a busy UI/logging thread in this process; 1-min load average "
        f"{load:.2f} on {os.cpu_count()} CPUs (other work on the machine inflates real-time figures)",
    ]
    return BenchResult("needle", figures, peers, {"real-time pacing": rows}, notes)
