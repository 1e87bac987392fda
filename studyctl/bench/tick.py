"""``studyctl bench tick``: where a virtual session's CPU goes — the participant, or everything else.

A simulated trial's tick runs the virtual participant, then the device, controller, scene, safety layer, loop and
sample sink. Their shares cannot be told apart by timers around each call (a timer costs as much as the smaller
calls) nor by a profiler (it inflates many small calls most). This benchmark splits them exactly, by replay:

1. a seeded cohort runs once while every action the participant returns is recorded (untimed);
2. the same cohort runs again as is (timed);
3. and again with the participant's ``act`` replaced by the recorded actions, in order (timed). Devices,
   controllers, scenes, the safety layer and the store see the same inputs, so they do the same work; the
   participant's own per-tick work is gone. ``replay_same_samples`` checks that the replayed sessions stored
   exactly the samples of the real ones (1.0), which is what makes the difference the participant's.

Figures per protocol (the demo's loop rates, :data:`studyctl.engine.loop_rates.SIM_RATE_HZ` for the tissue
loops): ``us_per_tick`` (CPU µs per loop tick, whole loop), ``participant_us_per_tick`` (what replay saved),
``other_us_per_tick`` (engine loop, safety layer, device, controller, scene, sample sink),
``participant_share`` of the loop, ``outside_loop_share`` (the session's CPU outside trial loops: store writes
and seals, scene and controller builds, breaks), and ``max_speedup_without_participant`` (session CPU over the
participant's CPU: the speed-up that making everything but the participant free would give, a bound on any
work outside ``studyctl/participants``).
"""

from __future__ import annotations

import contextlib
import hashlib
import sqlite3
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from studyctl.bench import BenchResult

SEED = 7
STUDIES = {  # protocol: (participants, quick participants; 0 = not in the quick run)
    "bio_inspired_palpation": (2, 1),
    "pseudo_haptic_palpation": (2, 1),
    "data_driven_palpation": (2, 0),
    "needle_insertion": (1, 0),
}


class _Recorder:
    """The participant, with every action it returns kept (a copy: the participant may reuse its objects)."""

    def __init__(self, real: Any, actions: list[Any]) -> None:
        from studyctl.plugins.interfaces import Action

        self._real, self._actions, self._action = real, actions, Action

    def begin_trial(self, info: Any, rng: Any) -> Any:
        return self._real.begin_trial(info, rng)

    def act(self, t: float, percept: Any) -> Any:
        a = self._real.act(t, percept)
        self._actions.append(self._action(dict(a.inputs), tuple(a.requests)))
        return a

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)


class _Replayer:
    """The participant with ``act`` answered from a recording; everything else (begin_trial's draws) is its own."""

    def __init__(self, real: Any, actions: list[Any]) -> None:
        self._real, self._next = real, iter(actions).__next__

    def begin_trial(self, info: Any, rng: Any) -> Any:
        return self._real.begin_trial(info, rng)

    def act(self, t: float, percept: Any) -> Any:
        return self._next()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)


@contextlib.contextmanager
def _loop_hook(mode: str, trials: list[list[Any]], spent: dict[str, float]) -> Iterator[None]:
    """Run every trial loop of this process through the recorder, the replayer or as is, timing its CPU."""
    import studyctl.engine.trial_exec as trial_exec

    real_run = trial_exec.run_trial
    played = iter(trials)

    def run_trial(**kw: Any) -> Any:
        if mode == "record":
            trials.append([])
            kw["participant"] = _Recorder(kw["participant"], trials[-1])
        elif mode == "replay":
            kw["participant"] = _Replayer(kw["participant"], next(played))
        c0 = time.process_time()
        out = real_run(**kw)
        spent["loop_s"] += time.process_time() - c0
        spent["ticks"] += out.ticks
        return out

    trial_exec.run_trial = run_trial
    try:
        yield
    finally:
        trial_exec.run_trial = real_run


def _samples_sha(database: Path) -> str:
    """sha256 of each stream's times and values as wholes (chunk boundaries follow wall time, not the data)."""
    con = sqlite3.connect(database)
    try:
        streams: dict[tuple, Any] = {}
        for row in con.execute("select trial_id, stream, channels, t, data from sample_chunk "
                               "order by trial_id, stream, chunk_index"):
            times, values = streams.setdefault(row[:3], (hashlib.sha256(), hashlib.sha256()))
            times.update(row[3])
            values.update(row[4])
        digests = {k: (times.hexdigest(), values.hexdigest()) for k, (times, values) in streams.items()}
        return hashlib.sha256(repr(digests).encode()).hexdigest()
    finally:
        con.close()


def _pass(protocol: str, n: int, rate: float | None, mode: str, trials: list[list[Any]], folder: Path) -> dict:
    from studyctl.workflows.simulate import simulate_study

    spent = {"loop_s": 0.0, "ticks": 0}
    ws = folder / mode
    with _loop_hook(mode, trials, spent):
        c0 = time.process_time()
        simulate_study(protocol, n, SEED, ws, sim_rate_hz=rate)
        spent["session_s"] = time.process_time() - c0
    spent["samples"] = _samples_sha(ws / "study.db")
    return spent


def split(protocol: str, n: int, rate: float | None) -> dict[str, float]:
    """The replay split of one seeded ``n``-person cohort of ``protocol`` (see the module docs)."""
    trials: list[list[Any]] = []
    with tempfile.TemporaryDirectory(prefix="studyctl-bench-tick-") as tmp:
        folder = Path(tmp)
        _pass(protocol, n, rate, "record", trials, folder)
        real = _pass(protocol, n, rate, "real", trials, folder)
        replay = _pass(protocol, n, rate, "replay", trials, folder)
    ticks = real["ticks"]
    participant_s = real["loop_s"] - replay["loop_s"]
    return {
        "ticks": float(ticks),
        "session_cpu_s": real["session_s"],
        "us_per_tick": 1e6 * real["loop_s"] / ticks,
        "participant_us_per_tick": 1e6 * participant_s / ticks,
        "other_us_per_tick": 1e6 * replay["loop_s"] / ticks,
        "participant_share": participant_s / real["loop_s"],
        "outside_loop_share": (real["session_s"] - real["loop_s"]) / real["session_s"],
        "max_speedup_without_participant": real["session_s"] / participant_s if participant_s > 0 else float("inf"),
        "replay_same_samples": float(real["samples"] == replay["samples"] and replay["ticks"] == ticks),
    }


def run(quick: bool = False) -> BenchResult:
    import os

    from studyctl.engine.loop_rates import SIM_RATE_HZ

    figures: dict[str, float] = {"load_1min_start": os.getloadavg()[0]}
    rows = []
    for protocol, (n_full, n_quick) in STUDIES.items():
        n = n_quick if quick else n_full
        if n == 0:
            continue
        got = split(protocol, n, SIM_RATE_HZ)
        rows.append({"protocol": protocol, "participants": n, **got})
        for key, value in got.items():
            figures[f"{key}_{protocol}"] = value
    figures["load_1min_end"] = os.getloadavg()[0]
    notes = [
        f"seeded cohorts (seed {SEED}) at the demo's loop rates; CPU seconds of this process; three passes each "
        "(record, real, replay), see the module docs",
        "max_speedup_without_participant bounds what any speed-up of the engine, devices, controllers, scenes and "
        "store can give while the participant's per-tick work stays as it is",
    ]
    if not all(r["replay_same_samples"] == 1.0 for r in rows):
        notes.append("a replayed cohort stored other samples than the real one: its split is not the participant's")
    return BenchResult("tick", figures, tables={"split": rows}, notes=notes)
