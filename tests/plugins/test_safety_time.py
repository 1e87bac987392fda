"""The safety layer treats tick time as input (issue 19): non-finite or backwards time → safe output and a
device_fault event; the gap after a bad tick still counts as a missed deadline; the balloon's 20 psi ceiling
(seed 000) is a safety limit."""

from __future__ import annotations

import math

import pytest

from studyctl.devices.palpation import BALLOON_CEILING_PSI, SimulatedPalpationDevice, palpation_limits
from studyctl.errors import ModelParameterError
from studyctl.models.palpation_hw import BalloonModel
from studyctl.plugins.interfaces import ChannelLimit, DeviceLimits
from studyctl.plugins.safety import SafetyLayer

LIMITS = DeviceLimits(outputs=(ChannelLimit("balloon_pct", 0, 100),), ramp_up_s=0.1)


def faults(events):
    return [(e["kind"], e["rule"]) for e in events if e["kind"] in ("device_fault", "device_recovered")]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, None, "1.0"])
def test_non_finite_time_during_ramp_up_is_safe_and_a_fault(bad):
    s = SafetyLayer(LIMITS, period_s=0.02)
    s.filter({"balloon_pct": 80.0}, 0.0)
    s.filter({"balloon_pct": 80.0}, 0.02)
    out = s.filter({"balloon_pct": 80.0}, bad)
    assert out == {"balloon_pct": 0.0}  # was balloon_pct: nan during ramp-up
    assert all(math.isfinite(v) for v in out.values())
    ev = s.drain_events()
    assert ("device_fault", "time_non_finite") in faults(ev)
    fault = next(e for e in ev if e["rule"] == "time_non_finite")
    assert math.isfinite(fault["t"]) and fault["tick_t"] == repr(bad)
    assert s.faulted


def test_gap_after_a_nan_tick_is_a_missed_deadline():
    s = SafetyLayer(LIMITS, period_s=0.02)
    for k in range(3):
        s.filter({"balloon_pct": 50.0}, 0.02 * k)
    s.filter({"balloon_pct": 50.0}, math.nan)
    s.drain_events()
    assert s.filter({"balloon_pct": 50.0}, 100.04) == {"balloon_pct": 0.0}  # 100 s after the last good tick
    ev = s.drain_events()
    assert ("device_fault", "missed_deadline") in faults(ev)
    gap = next(e for e in ev if e["rule"] == "missed_deadline")
    assert gap["gap_s"] == pytest.approx(100.0) and gap["missed"] >= 4999
    assert s.counts["missed_deadline"] == 1 and s.counts["time_non_finite"] == 1
    # good ticks again: recovered, ramping up from safe
    out = [s.filter({"balloon_pct": 50.0}, 100.04 + 0.02 * k)["balloon_pct"] for k in range(1, 9)]
    assert out[0] == 0.0 and out[-1] == pytest.approx(50.0)
    assert ("device_recovered", "missed_deadline") in faults(s.drain_events())


def test_backwards_time_is_a_fault_then_resyncs():
    s = SafetyLayer(LIMITS, period_s=0.02, deadline_factor=3.0)
    for k in range(10):
        s.filter({"balloon_pct": 50.0}, 0.02 * k)
    s.drain_events()
    assert s.filter({"balloon_pct": 50.0}, 0.05) == {"balloon_pct": 0.0}  # went back from 0.18 to 0.05
    assert ("device_fault", "time_backwards") in faults(s.drain_events())
    # time runs on from where it jumped to: no missed deadline, recovery and ramp-up
    got = [s.filter({"balloon_pct": 50.0}, 0.05 + 0.02 * k)["balloon_pct"] for k in range(1, 10)]
    ev = s.drain_events()
    assert ("device_recovered", "time_backwards") in faults(ev)
    assert ("device_fault", "missed_deadline") not in faults(ev)
    assert got[0] == 0.0 and got[-1] == pytest.approx(50.0)


def test_balloon_ceiling_is_a_safety_limit():
    balloon = BalloonModel()
    default = palpation_limits().channel("balloon_pct")
    assert default.high == 100.0  # 20 psi is reached at 116: the paper's 0-100 range stands
    assert BALLOON_CEILING_PSI == balloon.regulator_psi == 20.0
    low = palpation_limits(max_balloon_psi=10.0)
    s = SafetyLayer(low)
    out = s.filter({"balloon_pct": 100.0}, 0.0)
    s.filter({"balloon_pct": 100.0}, 1.0)
    out = s.filter({"balloon_pct": 100.0}, 2.0)
    assert out["balloon_pct"] == pytest.approx(76.0)
    assert balloon.static_psi(out["balloon_pct"]) == pytest.approx(10.0)
    assert "clamped" in [e["rule"] for e in s.drain_events()]
    with pytest.raises(ModelParameterError, match="max_balloon_psi"):
        palpation_limits(max_balloon_psi=25.0)
    device = SimulatedPalpationDevice({"max_balloon_psi": 5.0})
    assert device.limits.channel("balloon_pct").high == pytest.approx(56.0)
