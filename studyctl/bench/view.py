"""``studyctl bench view``: the participant view's latency and its cost to the 1 kHz loop.

Setup: seed 001's real-time condition (RT) — the needle_liver scene with its CT view, the needle_hybrid
controller with the protocol's RT parameters, the simulated 3-DoF device — run by :func:`run_trial` on the
real clock at 1 kHz, with a scripted hand sweeping the needle in and out so every CT frame differs.
Rounds alternate between

* **baseline** (the peer): the same trial without a view attached;
* **view**: the participant view attached (``ViewUI`` + ``ViewParticipant``) and streaming to a headless
  Chromium (Debian's ``/usr/bin/chromium``) that draws every frame it gets and echoes when it drew it;
* **coordinator**: the same, plus the coordinator's page open in a second headless Chromium, polling the
  board's state twice a second (the board is not bound to a store here: the database read it does at most
  every 2 s in a real session is not in this figure).

Figures
-------
``frame_latency_ms_p50/p99/max``
    From the state's timestamp (taken at the start of the tick that produced it, so an upper bound) to the
    end of the browser's draw in its ``requestAnimationFrame`` callback, in the server's clock (the page's
    clock is synchronised by round trips; ``clock_sync_rtt_ms`` bounds the error at half of it).
``frames_drawn_per_s``
    Frames the controlling browser drew per second (display rate 60 Hz).
``loop_overhead_pct``
    What the view takes of the 1 kHz loop's budget: the increase of the loop's mean busy time per tick
    (wall clock, from waking up to going back to sleep) with the view streaming to the browser, as a share
    of the 1 ms period (``loop_overhead_pct_with_coordinator``: with the coordinator's page open too,
    against the same baseline). ``loop_overhead_pct_of_work`` is the same increase relative to the loop's own busy
    time (stricter: this controller needs only a few tens of µs per tick). On a shared 2-core machine both
    include the browser competing for the CPU. ``loop_late_ticks_pct`` counts ticks that woke > 0.5 ms late.
``hook_us_per_tick``
    The view's own work inside the loop (frame slot, request inbox, tick time), measured without any
    contention: the same trial on the simulated clock with and without the view attached, loop-thread CPU
    time per tick (peer: ``loop_us_per_tick``, the loop without the view).
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Mapping
from dataclasses import asdict
from typing import Any

import numpy as np

from studyctl.bench import BenchResult
from studyctl.closing import stop_process
from studyctl.engine.clock import RealClock, SimulatedClock
from studyctl.engine.factory import EntryPointFactory, build_controller, build_device, build_scene, controller_needs
from studyctl.engine.plan import ReportSpec
from studyctl.engine.trial_loop import run_trial
from studyctl.engine.ui import Script, ScriptedUI
from studyctl.errors import NotFoundError
from studyctl.plugins.interfaces import Action, Participant, TrialInfo
from studyctl.view import ParticipantView

CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--window-size=1280,800", "--mute-audio",
)
COORDINATOR_SETTLE_S = 3.0
RT_PARAMS = {  # protocols/needle_insertion.yaml, condition RT (Table 1)
    "capsule": {"k_stiff": 100},
    "liver": {"k_cut": 5, "f_dynamic": 0.8, "f_static": 1.0, "c": 10},
    "tumour": {"k_stiff": 0, "k_cut": 7, "f_dynamic": 0.9, "f_static": 1.1, "c": 10.5},
    "radial": {"k_p": 100, "k_d": 30},
}


class _SweepHand(Participant):
    """A hand that pushes the needle in along the planned path and pulls it back, every 4 s."""

    name = "bench_sweep_hand"
    virtual = False

    def __init__(self, incision: np.ndarray, outward: np.ndarray) -> None:
        super().__init__()
        self.inc = incision
        self.out = outward

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        return None

    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        depth = 25.0 * (0.5 - 0.5 * math.cos(2.0 * math.pi * t / 4.0)) - 10.0  # 10 mm outside → 15 mm in
        p = self.inc - self.out * depth
        d = -self.out
        return Action({"x_mm": p[0], "y_mm": p[1], "z_mm": p[2], "dir_x": d[0], "dir_y": d[1], "dir_z": d[2],
                       "button": 1.0})


class _TimedClock(RealClock):
    """The real clock, noting each tick's busy time (wake-up to next sleep, wall and loop-thread CPU) and
    how late it woke."""

    def __init__(self) -> None:
        super().__init__()
        self.busy: list[float] = []
        self.cpu: list[float] = []
        self.late: list[float] = []
        self._woke: float | None = None
        self._woke_cpu = 0.0

    def sleep_until(self, t: float) -> None:
        entered = time.perf_counter()
        entered_cpu = time.thread_time()
        if self._woke is not None:
            self.busy.append(entered - self._woke)
            self.cpu.append(entered_cpu - self._woke_cpu)
        super().sleep_until(t)
        self._woke = time.perf_counter()
        self._woke_cpu = time.thread_time()
        self.late.append(self.now() - t)


def _hook_cost(seconds: float, rounds: int) -> tuple[float, float]:
    """(loop CPU µs per tick without the view, with the view attached but nobody watching)."""
    per: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(rounds):
        for attached in (False, True):
            view = ParticipantView() if attached else None
            try:
                t0 = time.thread_time()
                _trial(seconds, view, clock=SimulatedClock())  # no sleeping: CPU time is all there is
                per[attached].append((time.thread_time() - t0) / (seconds * 1000.0) * 1e6)
            finally:
                if view is not None:
                    view.close()
    return float(np.median(per[False])), float(np.median(per[True]))


def _trial(seconds: float, view: ParticipantView | None, clock: Any = None) -> Any:
    factory = EntryPointFactory()
    rng = np.random.default_rng(11)
    needs = controller_needs(factory, "needle_hybrid", RT_PARAMS, "realtime")
    scene = build_scene(factory, "needle_liver", {}, {"sites": {"tumour": 1}}, needs, rng)
    g = scene.geometry()
    inc, c = np.array(g.incision_mm), np.array(g.tumour_center_mm)
    hand: Participant = _SweepHand(inc, (inc - c) / np.linalg.norm(inc - c))
    controller = build_controller(factory, "needle_hybrid", RT_PARAMS, scene)
    device = build_device(factory, "sim_force3d", {}, scene, rng)
    ui: Any = ScriptedUI(Script())
    if view is not None:
        hand, ui = view.attach(hand, ui)
    info = TrialInfo("RT", seconds, 1000.0, "realtime",
                     {"requests": ["finish"], "report": asdict(ReportSpec()), "trial_index": 1})
    clock = clock if clock is not None else _TimedClock()
    start = clock.now()

    def should_stop() -> str | None:  # what the session engine does every tick
        ui.trial_tick(clock.now() - start)
        control = ui.poll_control()
        return control.kind if control is not None else None

    device.open()
    try:
        run_trial(info=info, controller=controller, device=device, participant=hand, clock=clock, rng=rng,
                  view=scene.view, should_stop=should_stop)
    finally:
        device.close()
    return clock


def _chromium() -> str:
    exe = os.environ.get("STUDYCTL_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
    if not os.path.exists(exe):
        raise NotFoundError("bench view needs a browser to draw the frames: Debian's Chromium was not found; "
                            "install it with `bash scripts/ensure-browser.sh` (or set STUDYCTL_CHROMIUM)")
    return exe


def _with_coordinator(exe: str, view: ParticipantView, seconds: float) -> dict[str, float]:
    """One view round with the coordinator's page open in a second browser (started for the round, so it polls
    only then)."""
    board = view.board
    with tempfile.TemporaryDirectory(prefix="studyctl-bench-coordinator-") as profile:
        return _coordinator_round(exe, profile, board, view, seconds)


def _coordinator_round(exe: str, profile: str, board: Any, view: ParticipantView, seconds: float
                       ) -> dict[str, float]:
    page = subprocess.Popen([exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", view.coordinator_url],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 30.0
        while board.polls < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        if board.polls < 2:
            raise NotFoundError(f"bench view: the headless browser ({exe}) did not open the coordinator page in 30 s")
        time.sleep(COORDINATOR_SETTLE_S)  # a freshly started browser keeps busy for a while after its first request
        before = board.polls
        stats = _stats(_trial(seconds, view))
        stats["polls_per_s"] = (board.polls - before) / seconds
        return stats
    finally:
        stop_process(page, 10.0)


def _stats(clock: _TimedClock, skip: int = 200) -> dict[str, float]:
    busy = np.array(clock.busy[skip:]) * 1e6
    cpu = np.array(clock.cpu[skip:]) * 1e6
    late = np.array(clock.late[skip:]) * 1e6
    return {"busy_us_mean": float(busy.mean()), "busy_us_p99": float(np.percentile(busy, 99)),
            "cpu_us_mean": float(cpu.mean()), "late_pct": float((late > 500.0).mean() * 100.0),
            "ticks": float(busy.size)}


def run(quick: bool = False) -> BenchResult:
    """Measure the view's frame latency and the loop's overhead (see the module docstring)."""
    seconds = 1.5 if quick else 3.0
    rounds = 2 if quick else 6
    # Safety events (missed deadlines on a loaded machine) are counted by the loop, not printed here.
    safety_log = logging.getLogger("studyctl.safety")
    level = safety_log.level
    safety_log.setLevel(logging.ERROR)
    try:
        return _run(seconds, rounds)
    finally:
        safety_log.setLevel(level)


def _run(seconds: float, rounds: int) -> BenchResult:
    exe = _chromium()
    base_rounds: list[dict[str, float]] = []
    view_rounds: list[dict[str, float]] = []
    coord_rounds: list[dict[str, float]] = []
    latencies: list[float] = []
    drawn_rates: list[float] = []
    rtts: list[float] = []
    _trial(0.3, None)  # warm caches and imports (scene textures, controller tables)
    loop_us, hooked_us = _hook_cost(seconds, 3)
    with tempfile.TemporaryDirectory(prefix="studyctl-bench-view-") as profile, ParticipantView() as view:
        hub = view.hub
        hub.show("trial", trial=1, condition="RT")
        browser = subprocess.Popen([exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", view.url],
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 30.0
            while not hub.clients and time.monotonic() < deadline:
                time.sleep(0.05)
            if not hub.clients:
                raise NotFoundError(f"bench view: the headless browser ({exe}) did not open the view in 30 s")
            time.sleep(1.0)  # let the page synchronise its clock
            for _ in range(rounds):
                base_rounds.append(_stats(_trial(seconds, None)))
                hub.latencies_ms.clear()
                clock = _trial(seconds, view)
                time.sleep(0.4)  # the last acknowledgements
                lat = list(hub.latencies_ms)
                latencies += lat
                drawn_rates.append(len(lat) / seconds)
                view_rounds.append(_stats(clock))
                hub.show("trial", trial=1, condition="RT")
                coord_rounds.append(_with_coordinator(exe, view, seconds))
                hub.show("trial", trial=1, condition="RT")
        finally:
            stop_process(browser, 10.0)
        rtts = list(hub.sync_rtt_ms.values())
    if not latencies:
        raise NotFoundError("bench view: the browser drew no frames (is the page blocked?)")
    lat = np.array(latencies)
    base_busy = float(np.median([r["busy_us_mean"] for r in base_rounds]))
    view_busy = float(np.median([r["busy_us_mean"] for r in view_rounds]))
    coord_busy = float(np.median([r["busy_us_mean"] for r in coord_rounds]))
    base_cpu = float(np.median([r["cpu_us_mean"] for r in base_rounds]))
    view_cpu = float(np.median([r["cpu_us_mean"] for r in view_rounds]))
    figures = {
        "frame_latency_ms_p50": float(np.percentile(lat, 50)),
        "frame_latency_ms_p99": float(np.percentile(lat, 99)),
        "frame_latency_ms_max": float(lat.max()),
        "frames_drawn_per_s": float(np.median(drawn_rates)),
        "loop_overhead_pct": 100.0 * (view_busy - base_busy) / 1000.0,
        "loop_overhead_pct_of_work": 100.0 * (view_busy - base_busy) / base_busy,
        "loop_overhead_pct_with_coordinator": 100.0 * (coord_busy - base_busy) / 1000.0,
        "loop_late_ticks_pct_with_coordinator": float(np.median([r["late_pct"] for r in coord_rounds])),
        "coordinator_polls_per_s": float(np.median([r["polls_per_s"] for r in coord_rounds])),
        "hook_us_per_tick": hooked_us - loop_us,
        "loop_busy_us_mean": view_busy,
        "loop_cpu_us_mean": view_cpu,
        "loop_busy_us_p99": float(np.median([r["busy_us_p99"] for r in view_rounds])),
        "loop_late_ticks_pct": float(np.median([r["late_pct"] for r in view_rounds])),
    }
    peers = {
        "loop_us_per_tick": loop_us,
        "loop_busy_us_mean": base_busy,
        "loop_cpu_us_mean": base_cpu,
        "loop_busy_us_p99": float(np.median([r["busy_us_p99"] for r in base_rounds])),
        "loop_late_ticks_pct": float(np.median([r["late_pct"] for r in base_rounds])),
    }
    if rtts:
        figures["clock_sync_rtt_ms"] = float(min(rtts))
    rows = [{"round": i + 1, "mode": mode, **r}
            for i, (b, v, c) in enumerate(zip(base_rounds, view_rounds, coord_rounds, strict=True))
            for mode, r in (("baseline", b), ("view", v), ("coordinator", c))]
    return BenchResult(
        name="view",
        figures=figures,
        peers=peers,
        tables={"rounds": rows},
        notes=[
            f"seed 001 RT trial at 1 kHz on the real clock, {rounds} × {seconds:g} s per mode, rounds alternated; "
            "peer = the same loop without the view (same run); the coordinator rounds add the coordinator's page "
            "in a second browser",
            "latency: state timestamp (start of the producing tick) → end of the draw in the browser's "
            "requestAnimationFrame callback, page clock synchronised to the server's by round trips",
            f"browser: {exe} headless; {len(lat)} frames acknowledged",
        ],
    )
