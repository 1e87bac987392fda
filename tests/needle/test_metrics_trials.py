"""Metrics from logged data, the controller against the shipped protocol, and whole virtual trials."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from needle_helpers import condition_params, table1

from studyctl.controllers.needle import NeedleHybridController
from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.errors import AnalysisError, ModelParameterError
from studyctl.models.needle import NeedleParams
from studyctl.models.needle_metrics import (
    NeedleTrialMetrics,
    count_scans,
    mean_tracking_error,
    needle_trial_metrics,
    targeting_error,
    trial_duration,
)
from studyctl.participants.needle_operator import VirtualNeedleOperator
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes.needle_liver import NeedleLiverScene

PROTOCOL = Path(__file__).resolve().parents[2] / "protocols" / "needle_insertion.yaml"
TRUTH = {
    "incision_mm": [0.0, 0.0, 30.0],
    "tumour_center_mm": [0.0, 0.0, -25.0],
    "liver_center_mm": [0.0, 0.0, -25.0],
    "liver_radius_mm": 55.0,
}


# ---------------------------------------------------------------- metrics
def test_metrics_on_a_known_path():
    t = np.arange(0, 10.0, 0.001)
    z = 40.0 - 7.0 * t  # from 10 mm above the incision to 30 mm past the tumour centroid… clipped below
    z = np.maximum(z, -24.0)  # stops 1 mm above the centroid
    x = np.where(z < 30.0, 2.0, 5.0)  # 2 mm off the path inside the liver, 5 mm outside
    samples = pd.DataFrame({"t": t, "x_mm": x, "y_mm": 0.0, "z_mm": z})
    events = [{"t": 1.0, "kind": "scan"}, {"t": 4.0, "kind": "scan"}, {"t": 9.9995, "kind": "trial_loop_end"}]
    m = needle_trial_metrics(samples, events, TRUTH)
    assert m.scans == 2 and count_scans(events) == 2
    assert m.duration_s == pytest.approx(9.9995)
    assert m.tracking_error_mm == pytest.approx(2.0)  # only samples inside the liver count
    assert m.targeting_error_mm == pytest.approx(math.hypot(2.0, 1.0))
    assert m.insertion_samples == int(((z < 30.0) & (np.hypot(x, z + 25) < 55)).sum())
    frame = m.to_frame()
    assert list(frame.columns) == list(NeedleTrialMetrics.COLUMNS) and len(frame) == 1
    # past the tumour the distance is to the segment's end (the centroid)
    beyond = pd.DataFrame({"t": [0.0], "x_mm": [0.0], "y_mm": [0.0], "z_mm": [-28.0]})
    assert mean_tracking_error(beyond, TRUTH) == pytest.approx(3.0)
    assert targeting_error(beyond, TRUTH) == pytest.approx(3.0)


def test_duration_is_capped_and_errors_are_clear():
    samples = pd.DataFrame({"t": [0.0, 95.0], "x_mm": 0.0, "y_mm": 0.0, "z_mm": 50.0})
    assert trial_duration(samples, [], 90.0) == 90.0
    assert trial_duration(samples, [{"kind": "trial_loop_end", "t": 12.5}], 90.0) == 12.5
    assert math.isnan(mean_tracking_error(samples, TRUTH))  # never inserted
    with pytest.raises(AnalysisError, match="x_mm"):
        needle_trial_metrics(pd.DataFrame({"t": [0.0]}), [], TRUTH)
    with pytest.raises(AnalysisError, match="tumour_center_mm"):
        targeting_error(samples, {"incision_mm": [0, 0, 0]})


# ---------------------------------------------------------------- controller and protocol
def test_shipped_protocol_conditions_are_table1(scene):
    data = yaml.safe_load(PROTOCOL.read_text())
    conds = {c["id"]: c for c in data["conditions"]}
    assert set(conds) == {"BL", "RT", "ES", "EG", "ESG"}
    for cid, cond in conds.items():
        assert cond["controller"] == "needle_hybrid"
        assert NeedleHybridController(cond["params"], scene).model_params == NeedleParams.from_mapping(table1(cid))
        assert cond["visual"] == ("realtime" if cid == "RT" else "on_request")


def test_controller_needs_the_liver_scene_and_reports_diagnostics(scene):
    with pytest.raises(ModelParameterError, match="needle_liver"):
        NeedleHybridController(condition_params("BL"), None)
    ctrl = NeedleHybridController(condition_params("ES"), scene)
    assert ctrl.rate_hz == 1000.0 and NeedleHybridController.needs({}) == frozenset({"layers"})
    from studyctl.plugins.interfaces import Observation

    g = scene.geometry()
    a, u = np.array(g.incision_mm), np.array(g.planned_direction)
    p = a + 5.0 * u
    cmd = ctrl.step(Observation(0.0, {"x_mm": p[0], "y_mm": p[1], "z_mm": p[2], "dir_x": u[0],
                                      "dir_y": u[1], "dir_z": u[2]}))  # fmt: skip
    assert set(cmd) == {"fx_n", "fy_n", "fz_n"}
    assert ctrl.diagnostics["layer"] == 1.0 and ctrl.diagnostics["depth_mm"] == pytest.approx(5.0, abs=0.01)
    assert [e["kind"] for e in ctrl.events] == ["capsule_contact"]
    # a faulted device gets no force
    assert ctrl.step(Observation(0.001, {"x_mm": p[0], "y_mm": p[1], "z_mm": p[2]}, faults=("jump",))) == {
        "fx_n": 0.0, "fy_n": 0.0, "fz_n": 0.0}  # fmt: skip


def test_a_device_fault_ends_the_trial_in_the_safe_state(scene):
    """A position jump mid-trial: the device latches zero force, the safety layer logs it, the loop ends."""
    from studyctl.plugins.interfaces import Action, Participant

    class Jumper(Participant):
        name = "jumper"

        def begin_trial(self, info, rng):
            pass

        def act(self, t, percept):
            x = 0.0 if t < 0.5 else 40.0  # an impossible 40 mm jump at 0.5 s
            return Action({"x_mm": x, "y_mm": 0.0, "z_mm": 40.0})

    device = SimulatedForceDevice({"hand": "none"}, scene)
    device.open()
    out = run_trial(
        info=TrialInfo("BL", 10.0, 1000.0, "none"),
        controller=NeedleHybridController(condition_params("BL"), scene),
        device=device,
        participant=Jumper(),
        clock=SimulatedClock(),
        rng=np.random.default_rng(0),
    )
    assert out.ended_by == "fault" and out.duration_s < 2.0
    faults = [e for e in out.events if e["kind"] == "device_fault"]
    assert faults and "jumped" in str(faults[0])
    assert device.feedback()["fx_n"] == 0.0


# ---------------------------------------------------------------- whole virtual trials
def _trial(condition: str, participant: VirtualNeedleOperator, site: int, seed: int):
    rng = np.random.default_rng(seed)
    scene = NeedleLiverScene.build({}, {"sites": {"tumour": site}}, frozenset({"layers", "view"}), rng)
    ctrl = NeedleHybridController(condition_params(condition), scene)
    device = SimulatedForceDevice({"device_class": "omega6"}, scene)
    device.open()
    rows: list[tuple[float, float, float, float]] = []
    visual = "realtime" if condition == "RT" else "on_request"
    out = run_trial(
        info=TrialInfo(condition, 90.0, 1000.0, visual),
        controller=ctrl,
        device=device,
        participant=participant,
        clock=SimulatedClock(),
        rng=rng,
        on_sample=lambda t, s: rows.append((t, s["x_mm"], s["y_mm"], s["z_mm"])),
        view=scene.view,
    )
    samples = pd.DataFrame(rows, columns=["t", "x_mm", "y_mm", "z_mm"])
    return out, needle_trial_metrics(samples, out.events, scene.truth())


def test_virtual_operator_reaches_the_tumour_through_the_simulator():
    op = VirtualNeedleOperator({})
    out, m = _trial("BL", op, site=2, seed=11)
    assert out.ended_by == "finish"
    assert m.scans == out.scans >= 2  # at least the planning scan and one check
    assert m.targeting_error_mm < 3.0 and m.tracking_error_mm < 3.0
    kinds = [e["kind"] for e in out.events]
    assert kinds.index("scan") < kinds.index("capsule_contact") < kinds.index("capsule_puncture")
    # same seed, fresh operator: the same trial
    out2, m2 = _trial("BL", VirtualNeedleOperator({}), site=2, seed=11)
    assert m2 == m


def test_waiting_for_the_live_view_does_not_let_guidance_pull_the_tip_into_the_liver():
    # With the real-time view the person used to wait with the button pressed: the radial guidance pulled its yielding
    # hand sideways onto the planned line, through the capsule (on main: ~8 withdrawals and re-entries per RT trial).
    op = VirtualNeedleOperator({})
    out, m = _trial("RT", op, site=1, seed=41)
    kinds = [e["kind"] for e in out.events]
    assert out.ended_by == "finish"
    assert kinds.count("capsule_contact") == 1 and "needle_withdrawn" not in kinds and "track_reused" not in kinds


@pytest.mark.slow
def test_realtime_view_needs_no_scans_and_enhanced_sensing_gives_a_cue():
    op = VirtualNeedleOperator({})
    out, m = _trial("RT", op, site=3, seed=5)
    assert m.scans == 0 and out.ended_by == "finish" and m.targeting_error_mm < 3.0
    # The typical person learns to trust the axial cue over repetitions, so the enhanced tumour is noticed in some
    # of 16 ES trials (5 when written) and the compliant BL tumour in the same 16 placements only as a rare false
    # alarm (1 when written: since b17a344 the faster hand's wobble can raise the axial force). A controller that
    # did not magnify the tumour force would make the two rates alike.
    def cues(condition: str) -> int:
        person = VirtualNeedleOperator({})
        for rep in range(16):
            out, _ = _trial(condition, person, site=4 + rep % 3, seed=20 + rep)
            assert out.ended_by == "finish"
        return sum(bool(h["cue"]) for h in person.history)

    es, bl = cues("ES"), cues("BL")
    assert es >= 4 and bl <= 2 and es >= bl + 3, (es, bl)


def test_likert_answers_are_valid_codes():
    op = VirtualNeedleOperator({})
    for cond in ("BL", "ESG"):
        _trial(cond, op, site=1, seed=3)
    rng = np.random.default_rng(0)
    for item in ("improved_vs_baseline", "easy_to_navigate", "confidence_increase", "haptic_equals_visual",
                 "easier_with_haptics", "quick_to_learn", "something else"):  # fmt: skip
        code = op.answer({"id": item, "text": "", "codes": [1, 2, 3, 4, 5], "condition": "ESG"}, rng)
        assert code in (1, 2, 3, 4, 5)


@pytest.mark.parametrize("rate", [1000.0, 250.0])
def test_the_maintain_blend_takes_its_time_in_seconds_at_any_loop_rate(scene, rate):
    """The trial loop tells the controller its rate (``set_loop_rate``). The maintain cross-fade advanced by one
    1 kHz tick's share of ``maintain_blend_s`` per step, so in a 250 Hz simulated loop it took 0.4 s instead of 0.1."""
    from studyctl.plugins.interfaces import Action, Participant

    class Releaser(Participant):
        name = "releaser"

        def begin_trial(self, info, rng):
            pass

        def act(self, t, percept):  # holds still above the liver and lets go of the button at 0.5 s
            return Action({"x_mm": 0.0, "y_mm": 0.0, "z_mm": 40.0, "button": 1.0 if t < 0.5 else 0.0})

    device = SimulatedForceDevice({"hand": "none"}, scene)
    device.open()
    ctrl = NeedleHybridController(condition_params("BL"), scene)
    blend: list[tuple[float, float]] = []
    run_trial(info=TrialInfo("BL", 1.0, rate, "none"), controller=ctrl, device=device, participant=Releaser(),
              clock=SimulatedClock(), rng=np.random.default_rng(0),
              on_sample=lambda t, s: blend.append((t, s["maintain"])))
    full = next(t for t, w in blend if w >= 1.0)
    assert full - 0.5 == pytest.approx(ctrl.model_params.maintain_blend_s, abs=1.5 / rate)
