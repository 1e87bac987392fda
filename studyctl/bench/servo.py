"""``studyctl bench servo``: real-time pacing of a 1 kHz trial loop in the servo process against the same loop in
the coordinator's process, with the other CPU core fully busy.

The loop: the needle insertion trial (``needle_hybrid`` controller, ESG scenario, ``sim_force3d`` device of the
omega.6 class, safety layer) at 1 kHz for ``seconds`` on a real clock, the participant idle. The load: a CPU hog
process pinned to the core the servo loop does not use (the bench starts and stops it), plus, in the coordinator's
process, a thread doing pure-Python work (the prompts, view and store a session keeps there).

- servo process: :func:`studyctl.engine.servo.run_trial_in_servo_process` with its real-time setup (CPU pinned,
  SCHED_FIFO when permitted else nice, gc frozen and disabled, hybrid sleep/spin wait); its measured ``rt`` report
  is in the notes.
- in-process (peer): the same loop run by :func:`studyctl.engine.trial_loop.run_trial` in this process beside the
  busy thread, with the same hybrid wait, without the real-time setup (the path a session took before).

Figures: ``period_jitter_us_p99_loaded`` (p99 of |period − 1 ms|), ``late_ticks_pct_loaded`` (ticks starting more
than 1 ms after they were due, %), lateness p99, the loop's CPU seconds, ``loop_cpu_steal_ms`` (what the hypervisor
took from the loop's CPU during the servo run: on a virtual machine the host stops a virtual CPU for milliseconds,
and the loop then runs the missed ticks late; ``scripts/servo_stalls.py`` traces which late ticks that explains),
and ``servo_start_s`` (wall seconds from
starting the servo process to the trial's time 0: spawn, imports, plugins built, device opened; paid once per
session) and ``servo_next_trial_start_s`` (the same for a following trial in the same process: plugins built,
device opened).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import threading
import time
from typing import Any

import numpy as np

from studyctl.bench import BenchResult, busy_python
from studyctl.bench.needle import _scenario  # as bench needle: Table 1 params
from studyctl.errors import BenchmarkError
from studyctl.plugins.interfaces import IdleParticipant, TrialInfo

RATE_HZ = 1000.0


def _hog(cpu: int | None, stop: Any) -> None:
    """Keep one core fully busy until told to stop."""
    if cpu is not None and hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, {cpu})
        except OSError:
            pass
    x = 0
    while not stop.is_set():
        for i in range(20000):
            x = (x + i * i) % 1_000_003


_SCENE = {"scene": "needle_liver", "placement": {"sites": {"tumour": 1}}, "needs": frozenset({"layers"})}


def _servo(seconds: float, cpu: int) -> tuple[dict[str, float], dict[str, Any]]:
    from studyctl.engine.servo import ServoProcess, ServoSpec  # noqa: PLC0415

    def spec(limit_s: float) -> ServoSpec:
        return ServoSpec(
            info=TrialInfo("ESG", limit_s, RATE_HZ, "none"), device="sim_force3d",
            device_params={"device_class": "omega6"}, controller="needle_hybrid", controller_params=_scenario("ESG"),
            scene=_SCENE["scene"], scene_placement=_SCENE["placement"], scene_needs=_SCENE["needs"], seed=2, cpu=cpu,
        )

    # as in a session: one servo process, the timed trial, then a short next trial in the same process
    with ServoProcess() as servo:
        result = servo.run_trial(spec(seconds), on_sample=lambda t, s: None)
        following = servo.run_trial(spec(0.2), on_sample=lambda t, s: None)
    if result.timing is None:
        raise BenchmarkError("the servo process reported no timing, so there are no jitter or lateness figures")
    return result.timing.as_dict(), {**result.rt, "start_s": result.start_s, "next_start_s": following.start_s,
                                     "same_process": following.rt.get("pid") == result.rt.get("pid")}


def _in_process(seconds: float) -> tuple[dict[str, float], float]:
    from studyctl.controllers.needle import NeedleHybridController  # noqa: PLC0415
    from studyctl.devices.force3d import SimulatedForceDevice  # noqa: PLC0415
    from studyctl.engine.realtime import TimedClock  # noqa: PLC0415
    from studyctl.engine.trial_loop import run_trial  # noqa: PLC0415
    from studyctl.scenes.needle_liver import NeedleLiverScene  # noqa: PLC0415

    rng = np.random.default_rng(2)
    scene = NeedleLiverScene.build({}, _SCENE["placement"], _SCENE["needs"], rng)
    ctrl = NeedleHybridController(_scenario("ESG"), scene)
    device = SimulatedForceDevice({"device_class": "omega6"}, scene)
    device.open()
    clock = TimedClock(capacity=int(seconds * RATE_HZ) + 16)
    samples: list[Any] = []
    c0 = time.process_time()
    quiet = logging.getLogger("studyctl")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # its missed deadlines are counted below, not printed one by one
    try:
        run_trial(info=TrialInfo("ESG", seconds, RATE_HZ, "none"), controller=ctrl, device=device,
                  participant=IdleParticipant(), clock=clock, rng=rng, on_sample=lambda t, s: samples.append(s))
    finally:
        quiet.setLevel(level)
        device.close()
    return clock.timing(1.0 / RATE_HZ).as_dict(), time.process_time() - c0


def run(quick: bool = False) -> BenchResult:
    seconds = 2.0 if quick else 10.0
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else [0]
    servo_cpu = cpus[-1]
    hog_cpu = cpus[0] if len(cpus) > 1 else None
    ctx = mp.get_context("spawn")
    stop_hog = ctx.Event()
    hog = ctx.Process(target=_hog, args=(hog_cpu, stop_hog), name="studyctl-bench-hog", daemon=True)
    stop_ui = threading.Event()
    ui = threading.Thread(target=busy_python, args=(stop_ui,), daemon=True)
    load0 = os.getloadavg()[0]
    w0 = time.perf_counter()
    hog.start()
    ui.start()
    try:
        time.sleep(0.5)  # the hog is spinning
        servo, rt = _servo(seconds, servo_cpu)
        inproc, inproc_cpu = _in_process(seconds)
    finally:
        stop_ui.set()
        stop_hog.set()
        ui.join()
        hog.join(timeout=5)
        if hog.is_alive():
            hog.terminate()
            hog.join()
    wall = time.perf_counter() - w0
    load1 = os.getloadavg()[0]

    def figs(t: dict[str, float]) -> dict[str, float]:
        return {
            "period_jitter_us_p99_loaded": float(t["period_jitter_us_p99"]),
            "late_ticks_pct_loaded": 100.0 * float(t["late_1ms"]) / max(1.0, float(t["ticks"])),
            "late_us_p99_loaded": float(t["late_us_p99"]),
            "period_jitter_us_max_loaded": float(t["period_jitter_us_max"]),
        }

    # what a session pays before its first hardware trial's loop runs (spawn, imports, plugins built, device opened)
    # and before each following one (plugins built, device opened)
    figures = {**figs(servo), "loop_cpu_s": float(rt.get("cpu_s", float("nan"))),
               # what the hypervisor took from the loop's CPU meanwhile (/proc/stat steal; NaN where unknown)
               "loop_cpu_steal_ms": float(rt.get("steal_ms", float("nan"))),
               "servo_start_s": float(rt.pop("start_s", float("nan"))),
               "servo_next_trial_start_s": float(rt.pop("next_start_s", float("nan")))}
    peers = {**figs(inproc), "loop_cpu_s": inproc_cpu}
    cols = ("ticks", "late_us_p50", "late_us_p99", "late_1ms", "period_jitter_us_p50", "period_jitter_us_p99",
            "period_jitter_us_max")
    rows = [
        {"loop": "servo process", **{k: round(float(servo[k]), 1) for k in cols}},
        {"loop": "in-process (peer)", **{k: round(float(inproc[k]), 1) for k in cols}},
    ]
    notes = [
        f"{seconds:g} s of the 1 kHz needle ESG loop per path; a CPU hog process pinned to CPU {hog_cpu} "
        f"(the servo loop is pinned to CPU {servo_cpu}) and a busy Python thread in the coordinator's process",
        f"servo process real-time setup as measured in the child: {rt}",
        f"loop CPU seconds: servo {figures['loop_cpu_s']:.2f} s, in-process {inproc_cpu:.2f} s (incl. the busy "
        f"thread's share of this process); bench wall time {wall:.1f} s",
        f"1-min load average {load0:.2f} before, {load1:.2f} after, on {os.cpu_count()} CPUs (shared machine)",
    ]
    return BenchResult("servo", figures, peers, {"real-time pacing with the other core busy": rows}, notes)
