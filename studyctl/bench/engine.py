"""``studyctl bench engine``: how fast the session engine runs virtual trials, and what a commit costs.

Figures
-------
virtual_trials_per_s (and virtual_trials_per_cpu_s: per CPU second of this process, for a shared machine)
    60-simulated-second, 50 Hz palpation-style trials per wall second, through the whole engine: a
    :class:`~studyctl.engine.session.SessionRunner` on the SQLite study store (samples through the
    buffered SampleWriter, events and step commits durable), with a trivial controller, a one-line scene,
    a simulated device and a participant that probes and never finishes (each trial runs to its limit).
    Goal: ≥ 20.
event_commit_ms_p99 (and _p50)
    Wall time of one durable event commit (``Recorder.event``) on SQLite with ``synchronous=FULL``.

Tables: the same trial on the in-memory recorder (engine without I/O), and the seed-000 palpation stack
(sponge phantom, simulated board, linear controller, virtual palpator) when its plugins are installed.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from studyctl.bench import BenchResult
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.factory import MappingFactory
from studyctl.engine.plan import ConditionSpec, ReportSpec, SessionPlan, Step
from studyctl.engine.recorder import MemoryRecorder
from studyctl.engine.session import SessionRunner
from studyctl.engine.store_recorder import StoreRecorder
from studyctl.engine.ui import VirtualUI
from studyctl.errors import BenchmarkError, PluginError
from studyctl.plugins.interfaces import (
    Action,
    ChannelLimit,
    Controller,
    Device,
    DeviceLimits,
    Observation,
    Participant,
    Scene,
)
from studyctl.store import StudyStore

TRIAL_S = 60.0
RATE_HZ = 50.0


class _LineScene(Scene):
    name = "bench_line"

    @classmethod
    def build(cls, spec, placement, needs, rng):
        return cls()

    def sense(self, inputs):
        return {"force_n": 0.05 * max(inputs.get("z_mm", 0.0), 0.0)}


class _Device(Device):
    name = "bench_device"
    limits = DeviceLimits(outputs=(ChannelLimit("balloon_pct", 0.0, 100.0, safe=0.0),))

    def __init__(self, scene=None, rng=None, params=None):
        self.scene = scene
        self.inputs: dict[str, float] = {}
        self.out: dict[str, float] = {}

    def open(self):
        pass

    def apply_input(self, inputs):
        self.inputs = inputs

    def read(self, t):
        return Observation(t, self.scene.sense(self.inputs))

    def write(self, command):
        self.out = command

    def feedback(self):
        return self.out

    def close(self):
        self.out = self.limits.safe_command()


class _Linear(Controller):
    name = "bench_linear"
    rate_hz = RATE_HZ

    def reset(self):
        pass

    def step(self, obs):
        return {"balloon_pct": 20.0 * obs.values["force_n"]}


class _Prober(Participant):
    name = "bench_prober"

    def begin_trial(self, info, rng):
        self.phase = float(rng.uniform(0, 1))

    def act(self, t, percept):
        return Action({"x_mm": 10.0 * t, "z_mm": 5.0 * (1.0 + np.sin(t + self.phase))})


_PLUGINS = {"scene": {"bench_line": _LineScene}, "device": {"bench_device": _Device},
            "controller": {"bench_linear": _Linear}, "participant": {"bench_prober": _Prober}}


def _plan(n_trials: int) -> SessionPlan:
    steps = tuple(Step(i, "trial", "linear", 1, i, i, TRIAL_S, data={"placement": {}}) for i in range(1, n_trials + 1))
    return SessionPlan(
        steps=steps, conditions={"linear": ConditionSpec("linear", controller="bench_linear")},
        report=ReportSpec("none"), scene="bench_line", simulated_device={"plugin": "bench_device", "params": {}},
        virtual_participant={"plugin": "bench_prober", "params": {}}, study="bench",
    )


def _runner(rec, factory) -> SessionRunner:
    p = _Prober()
    return SessionRunner(rec, ui=VirtualUI(p, lambda a, b: np.random.default_rng(0)), participant=p,
                         clock=SimulatedClock(), factory=factory, virtual=True)


def _store(folder: Path, name: str) -> tuple[StudyStore, int]:
    store = StudyStore.create(folder / f"{name}.db")
    study = store.create_study(name, seed=1)
    return store, store.add_participant(study.id, "BENCH").id


def _palpation_trials_per_s(folder: Path, n: int) -> tuple[float, float] | None:
    """The seed-000 stack on the store, if its plugins are installed (else None)."""
    from studyctl.engine.factory import EntryPointFactory, build_participant

    factory = EntryPointFactory()
    try:
        for kind, name in (("scene", "sponge_phantom"), ("device", "sim_palpation"), ("controller", "linear"),
                           ("participant", "virtual_palpator")):
            factory.load(kind, name)
    except PluginError:
        return None
    steps = tuple(
        Step(i, "trial", "linear", 1, i, i, TRIAL_S,
             data={"placement": {"sites": {"soft": 1 + (i % 7), "medium": 1 + ((i + 2) % 7),
                                           "hard": 1 + ((i + 4) % 7)}, "orientation_deg": None}})
        for i in range(1, n + 1)
    )
    plan = SessionPlan(
        steps=steps, conditions={"linear": ConditionSpec("linear", controller="linear")},
        report=ReportSpec("grid", columns=tuple("1234567"), rows=tuple("1234567")), scene="sponge_phantom",
        simulated_device={"plugin": "sim_palpation", "params": {}},
        virtual_participant={"plugin": "virtual_palpator", "params": {}}, study="bench",
    )
    store, pid = _store(folder, "palpation")
    try:
        rec = StoreRecorder.create(store, pid, plan, seed=3, virtual=True)
        p = build_participant(factory, "virtual_palpator", {})
        runner = SessionRunner(rec, ui=VirtualUI(p, lambda a, b: np.random.default_rng(0)), participant=p,
                               clock=SimulatedClock(), factory=factory, virtual=True)
        t0, c0 = time.perf_counter(), time.process_time()
        runner.run()
        return n / (time.perf_counter() - t0), n / (time.process_time() - c0)
    finally:
        store.close()


def run(quick: bool = False) -> BenchResult:
    n_trials = 5 if quick else 40
    n_commits = 50 if quick else 400
    factory = MappingFactory(_PLUGINS)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        # engine + store
        store, pid = _store(folder, "engine")
        try:
            rec = StoreRecorder.create(store, pid, _plan(n_trials), seed=1, virtual=True)
            t0, c0 = time.perf_counter(), time.process_time()
            result = _runner(rec, factory).run()
            store_s = time.perf_counter() - t0
            store_cpu = time.process_time() - c0
            ticks = [t.outcome["ticks"] for t in store.list_trials() if t.status == "completed"]
            if result.trials_completed != n_trials or any(k != int(TRIAL_S * RATE_HZ) for k in ticks):
                raise BenchmarkError(f"bench session did not run {n_trials} full trials: {result}, ticks {ticks}")
            samples = len(store.read_samples(store.list_trials()[0].id))
            # event commits: durable (fsynced) and process-crash-safe only
            lat = np.empty(n_commits)
            lat_nd = np.empty(n_commits)
            for i in range(n_commits):
                c0 = time.perf_counter()
                rec.event("bench_event", {"i": i, "note": "durable commit"}, t=float(i), durable=True)
                c1 = time.perf_counter()
                rec.event("bench_event", {"i": i, "note": "not fsynced"}, t=float(i), durable=False)
                lat[i] = c1 - c0
                lat_nd[i] = time.perf_counter() - c1
        finally:
            store.close()
        # engine without I/O
        mem = MemoryRecorder(_plan(n_trials), seed=1)
        t0, c0 = time.perf_counter(), time.process_time()
        _runner(mem, factory).run()
        mem_s = time.perf_counter() - t0
        mem_cpu = time.process_time() - c0
        palp_n = 2 if quick else 6
        palpation = _palpation_trials_per_s(folder, palp_n)
    figures = {
        "virtual_trials_per_s": n_trials / store_s,
        "virtual_trials_per_cpu_s": n_trials / store_cpu,
        "event_commit_ms_p99": float(np.percentile(lat, 99) * 1e3),
        "event_commit_ms_p50": float(np.percentile(lat, 50) * 1e3),
        "event_commit_nondurable_ms_p99": float(np.percentile(lat_nd, 99) * 1e3),
    }
    table = [
        {"variant": "engine + SQLite store (figure)", "trials_per_s": n_trials / store_s,
         "trials_per_cpu_s": n_trials / store_cpu, "ticks_per_s": n_trials * TRIAL_S * RATE_HZ / store_s},
        {"variant": "engine, in-memory recorder", "trials_per_s": n_trials / mem_s,
         "trials_per_cpu_s": n_trials / mem_cpu, "ticks_per_s": n_trials * TRIAL_S * RATE_HZ / mem_s},
    ]
    if palpation is not None:
        table.append({"variant": "seed-000 stack: sponge + sim board + linear + virtual palpator, store",
                      "trials_per_s": palpation[0], "trials_per_cpu_s": palpation[1],
                      "ticks_per_s": palpation[0] * TRIAL_S * RATE_HZ})
    return BenchResult(
        name="engine",
        figures=figures,
        tables={"trial throughput (60 simulated s at 50 Hz per trial)": table},
        notes=[
            f"{n_trials} trials of {TRIAL_S:.0f} simulated s at {RATE_HZ:.0f} Hz ({samples} samples stored per "
            "trial) on a SessionRunner with the SQLite StoreRecorder; trivial controller/scene/device/participant",
            f"event commit: {n_commits} durable commits of one event (SQLite WAL, synchronous=FULL; the engine "
            "uses these for answers, scans, reports, trial results and step completions) and as many "
            "non-fsynced ones (step/trial start, in-trial events: safe against a killed process, made "
            "power-cut safe by the next durable commit)",
            "no peer: no other experiment engine with per-trial durable commits and resume is installable here",
            "*_per_cpu_s: per second of this process's CPU time (the machine is shared; wall figures depend on "
            "the load; CPU time excludes waiting for fsync)",
        ],
    )
