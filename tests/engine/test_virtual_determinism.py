"""The per-tick fast paths (safety layer, sample buffering) change speed, never results.

Each fast path has a general path next to it that handles everything (the one the code had before).
These tests run the same input once through the fast paths and once with them forced off, and require
bit-identical outputs: the filter's writes and events for adversarial command/sensor sequences, and a
whole seeded virtual needle session (samples, events, trial outcomes) through the real engine.
"""

from __future__ import annotations

import hashlib
import math
import sqlite3
from pathlib import Path

import numpy as np
import pytest

import studyctl.engine.sample_buffer as sample_buffer
import studyctl.plugins.safety as safety
from studyctl.plugins.interfaces import ChannelLimit, DeviceLimits, Observation

# An _active key no rule ever uses: with it present every fast path of SafetyLayer.filter is skipped.
_NEVER = ("__fast_path_off__", "")


def _slow(monkeypatch: pytest.MonkeyPatch) -> None:
    """Force the general paths: safety filter, sensor finiteness scan and the recorder's object rows."""
    init = safety.SafetyLayer.__init__

    def slow_init(self, *args, **kwargs) -> None:  # noqa: ANN001
        init(self, *args, **kwargs)
        self._active[_NEVER] = (0.0, 0)

    monkeypatch.setattr(safety.SafetyLayer, "__init__", slow_init)
    monkeypatch.setattr(safety, "_all_finite_floats", lambda values: False)
    samples_init = sample_buffer.StoreSamples.__init__

    def rows_init(self, *args, **kwargs) -> None:  # noqa: ANN001
        samples_init(self, *args, **kwargs)
        self._flat = None

    monkeypatch.setattr(sample_buffer.StoreSamples, "__init__", rows_init)


def _limits(rate: float | None) -> DeviceLimits:
    return DeviceLimits(
        outputs=tuple(ChannelLimit(c, -3.0, 3.0, 0.0, rate, "N") for c in ("fx_n", "fy_n", "fz_n"))
        + (ChannelLimit("valve", 0.0, 1.0, 0.0, None, ""),),
        max_force_n=4.0,
        ramp_up_s=0.05,
    )


def _run_filter(rate: float | None) -> list:
    """Feed a seeded adversarial sequence of commands and sensor readings through one SafetyLayer."""
    rng = np.random.default_rng(7)
    layer = safety.SafetyLayer(_limits(rate), period_s=0.001)
    odd = [math.nan, math.inf, -math.inf, None, "1.0", True, 2, np.float64(math.nan), np.float32(0.5), 10**400]
    out = []
    for k in range(3000):
        t = k * 0.001 + (0.01 if k == 1500 else 0.0)  # one missed deadline
        command: object = {
            "fx_n": float(rng.normal(0, 2)),
            "fy_n": np.float64(rng.normal(0, 2)),
            "fz_n": float(rng.normal(0, 1)),
            "valve": float(rng.uniform(-0.2, 1.2)),
        }
        r = rng.random()
        if r < 0.03:
            command["fy_n"] = odd[int(rng.integers(len(odd)))]
        elif r < 0.04:
            command["extra"] = 1.0
        elif r < 0.045:
            command = [1.0, 2.0]
        sensed = {"x_mm": float(rng.normal()), "v": np.float64(rng.normal()), "b": 1.0}
        if rng.random() < 0.01:
            sensed["x_mm"] = odd[int(rng.integers(len(odd)))]
        elif rng.random() < 0.005:
            sensed = {"x_mm": 1e308, "y_mm": 1e308}  # finite, but its sum overflows
        out.append(layer.filter(command, t, Observation(t, sensed)))
        out.append(layer.drain_events())
    return out


@pytest.mark.parametrize("rate", [None, 500.0])
def test_safety_fast_paths_match_the_general_path(monkeypatch: pytest.MonkeyPatch, rate: float | None) -> None:
    fast = _run_filter(rate)
    _slow(monkeypatch)
    slow = _run_filter(rate)
    assert repr(fast) == repr(slow)
    events = [ev for e in fast if isinstance(e, list) for ev in e]
    rules = {ev["rule"] for ev in events}
    assert {"sensor_non_finite", "missed_deadline", "non_finite_command", "clamped", "force_norm"} <= rules
    assert {"unknown_channel", "invalid_command"} <= rules


def _session_digest(out: Path) -> dict[str, str]:
    """Run one seeded virtual needle participant the way ``studyctl simulate`` does; hash what it stored."""
    from studyctl.engine.api import run_session
    from studyctl.store.enrollment import enroll, study_protocol
    from studyctl.store.workspace import init_workspace, open_study
    from studyctl.workflows.simulate import relax_sqlite_durability

    init = init_workspace(out, protocol="needle_insertion", seed=1, db=None)
    with open_study(None, str(init.root), init.study) as opened:
        relax_sqlite_durability(opened.store)
        study_protocol(opened.study)
        code = enroll(opened.store, None, study=opened.study.name).code
        # a fixed session seed: participant codes are random, and the default seed derives from the code
        run_session(opened.store, code, study=opened.study.name, virtual=True, seed=424242)
    con = sqlite3.connect(init.database)
    try:
        digest = {}
        trials = con.execute("select plan_position, condition, status, outcome from trial order by id")
        digest["trials"] = repr(list(trials))
        digest["events"] = repr(
            list(con.execute("select trial_id, kind, payload from event where kind != 'session_process' order by id"))
        )
        streams: dict[tuple, list] = {}
        # chunk boundaries follow wall time: compare each stream's times and values as wholes
        for row in con.execute(
            "select trial_id, stream, channels, dtype, t, data from sample_chunk order by trial_id, stream, chunk_index"
        ):
            h = streams.setdefault(row[:4], [hashlib.sha256(), hashlib.sha256()])
            h[0].update(row[4])
            h[1].update(row[5])
        digest["samples"] = repr({k: (a.hexdigest(), b.hexdigest()) for k, (a, b) in streams.items()})
    finally:
        con.close()
    return digest


@pytest.mark.slow
def test_virtual_needle_session_is_bit_identical_without_fast_paths(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fast = _session_digest(tmp_path / "fast")
    _slow(monkeypatch)
    slow = _session_digest(tmp_path / "slow")
    assert fast["trials"] == slow["trials"]
    assert fast["events"] == slow["events"]
    assert fast["samples"] == slow["samples"]
    assert "completed" in fast["trials"]
