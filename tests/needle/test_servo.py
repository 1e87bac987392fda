"""The servo process: a trial's real-time loop in its own process, samples and timing come back."""

from __future__ import annotations

import numpy as np
import pytest
from needle_helpers import condition_params

from studyctl.engine.servo import ServoSpec, ServoTiming, run_trial_in_servo_process
from studyctl.errors import DeviceError
from studyctl.plugins.interfaces import Request, TrialInfo


def test_timing_statistics_from_tick_starts():
    starts = np.array([0.0, 0.001, 0.0021, 0.0030, 0.0052, 0.0060])
    t = ServoTiming.from_starts(starts, 0.001)
    assert t.ticks == 6 and t.overruns == 1  # 5.2 ms was scheduled at 4 ms
    assert t.period_jitter_us_max == pytest.approx(1200.0)
    assert t.late_us_max == pytest.approx(1200.0)


@pytest.mark.slow  # starts the servo process; the trial runs on the real clock
def test_trial_runs_in_a_servo_process_and_streams_back():
    spec = ServoSpec(
        info=TrialInfo("ESG", 0.6, 1000.0, "on_request"),
        device="sim_force3d",
        controller="needle_hybrid",
        controller_params=condition_params("ESG"),
        scene="needle_liver",
        scene_placement={"sites": {"tumour": 1}},
        scene_needs=frozenset({"layers"}),
        seed=4,
    )
    samples, events = [], []
    sent = [False]

    def requests():
        if not sent[0]:
            sent[0] = True
            return [Request("scan")]
        return []

    result = run_trial_in_servo_process(
        spec,
        on_sample=lambda t, s: samples.append((t, dict(s))),
        on_event=lambda t, k, p: events.append(k),
        requests=requests,
    )
    assert result.ended_by == "time_limit"
    assert len(samples) == result.ticks > 0
    assert {"x_mm", "fx_n", "depth_mm"} <= set(samples[0][1])
    assert "servo_timing" in events and result.timing is not None and result.timing.ticks >= result.ticks
    assert result.scans == 1  # the parent's scan request reached the loop


@pytest.mark.slow  # starts the servo process; the trial runs on the real clock
def test_a_failing_servo_process_raises_with_the_reason():
    spec = ServoSpec(info=TrialInfo("BL", 0.2, 1000.0, "none"), device="no_such_device")
    with pytest.raises(DeviceError, match="no_such_device"):
        run_trial_in_servo_process(spec)
