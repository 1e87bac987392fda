"""Manual palpation (seeds 002/003) with virtual participants: the simulated bare finger (``direct_touch``)
feels the phantom's own reaction force, the engine runs the manual trial through it, and the outcome is
recorded exactly as a coordinator's entry for a person."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from studyctl.cli.app import main
from studyctl.controllers.tissue import StiffnessMapForceFeedback
from studyctl.devices.direct_touch import DirectTouchDevice
from studyctl.engine.api import run_session
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.errors import DeviceError, ModelParameterError
from studyctl.models.palpation_metrics import chance_hit_probability, score_trial
from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.plugins.interfaces import Observation, TrialInfo
from studyctl.resources import find_shipped
from studyctl.scenes.tissue import StiffnessTissueScene
from studyctl.store.enrollment import enroll
from studyctl.store.workspace import init_workspace, open_study

NEEDS = frozenset({"stiffness_map", "surface"})


def _scene(orientation: float = 0.0, **options) -> StiffnessTissueScene:
    spec = {"phantom": "seed003_block", "phantom_options": options} if options else {}
    return StiffnessTissueScene.build(spec, {"orientation_deg": orientation}, NEEDS, np.random.default_rng(0))


def _touch(device: DirectTouchDevice, t: float, x: float, y: float, z: float) -> dict[str, float]:
    device.apply_input({"x_mm": x, "y_mm": y, "z_mm": z})
    device.read(t)
    device.write({})
    return dict(device.feedback())


# ------------------------------------------------------------------------------------------ the device


@pytest.mark.slow
def test_the_finger_feels_the_ff_force_model_without_the_device_clamp():
    """Same physical model as the FF controller, but no 3.3 N clamp and the tissue pushes back on retraction."""
    scene = _scene(tissue_kpa=60.0)  # a stiffer block, so deep presses exceed an Omni's 3.3 N
    finger = DirectTouchDevice({}, scene)
    finger.open()
    ff = StiffnessMapForceFeedback({}, scene)  # seed 003 defaults: 3.3 N clamp, no normal force on retraction
    wide = StiffnessMapForceFeedback({"max_force_n": 50.0, "release_on_retract": False}, scene)
    ff.reset()
    wide.reset()
    x, y = 40.0, 60.0
    felt = []
    for k, depth in enumerate([0.0, 2.0, 4.0, 6.0, 6.5, 5.0]):  # press in, then withdraw a little
        z = 25.0 - depth
        fb = _touch(finger, 0.02 * k, x, y, z)
        obs = Observation(0.02 * k, {"x_mm": x, "y_mm": y, "z_mm": z})
        ref = wide.step(obs)
        clamped = ff.step(obs)
        assert fb["fz_n"] == pytest.approx(ref["fz_n"], rel=1e-12, abs=1e-12)
        assert fb["direct_touch"] == 1.0 and (fb["x_mm"], fb["y_mm"], fb["z_mm"]) == (x, y, z)
        felt.append((fb["fz_n"], clamped["fz_n"]))
    deepest = felt[4]
    assert deepest[0] > 3.3 and deepest[1] == pytest.approx(3.3)
    assert felt[5][0] > 1.0 and felt[5][1] == 0.0  # withdrawing: the real block still pushes, the FF render does not
    assert felt[0] == (0.0, 0.0)
    assert finger.limits.outputs == ()  # nothing to actuate
    finger.close()


@pytest.mark.slow
def test_the_finger_needs_a_phantom_and_refuses_bad_input():
    with pytest.raises(ModelParameterError, match="needs a stiffness_tissue scene"):
        DirectTouchDevice({}, None)
    with pytest.raises(ModelParameterError, match="unknown"):
        DirectTouchDevice({"max_force": 3.3}, _scene())
    finger = DirectTouchDevice({}, _scene())
    with pytest.raises(DeviceError, match="before open"):
        finger.apply_input({"x_mm": 1.0, "y_mm": 1.0, "z_mm": 30.0})
    finger.open()
    with pytest.raises(DeviceError, match="non-finite"):
        finger.apply_input({"x_mm": math.nan, "y_mm": 1.0, "z_mm": 30.0})


# ------------------------------------------------------------------------------------------ perception


def _manual_trials(scene_for, seeds, *, count: int | None = None):
    """Virtual manual trials through the trial loop; returns (reports, truth, duration) per trial.

    The participant palpates ``scene_for(k)``; hits are scored against the truth of the seed 003 block at the
    same orientation (the nodules the participant should find if it finds anything)."""
    out = []
    for k in seeds:
        orientation = 90.0 * (k % 4)
        scene = scene_for(orientation)
        truth = _scene(orientation).truth()["nodules"]
        finger = DirectTouchDevice({}, scene)
        finger.open()
        public = dict(scene.public())
        if count is not None:
            public["nodule_count"] = count
        participant = VirtualTissuePalpator({})
        info = TrialInfo(condition="manual", time_limit_s=1800.0, rate_hz=50.0, visual="none", public=public)
        outcome = run_trial(info=info, controller=None, device=finger, participant=participant,
                            clock=SimulatedClock(), rng=np.random.default_rng(1000 + k))
        finger.close()
        assert outcome.ended_by == "finish"
        assert participant.perceived["cues"] == ["force"]  # it felt the tissue, saw no cursor
        out.append((outcome.reports, truth, outcome.duration_s))
    return out


@pytest.mark.slow
def test_manual_detection_comes_from_touch_not_from_the_truth():
    from scipy.stats import binom

    p_chance = chance_hit_probability(_scene().truth()["nodules"], 10.0, (0.0, 120.0, 0.0, 120.0))
    assert p_chance < 0.1
    seeds = range(4)

    def pooled(trials):
        hits = reports = found = 0
        for reps, truth, duration in trials:
            sc = score_trial(reps, truth, hit_radius_mm=10.0, duration_s=duration)
            hits, reports, found = hits + sc.hits, reports + sc.reports, found + sc.nodules_found
        return hits, reports, found

    with_nodules = _manual_trials(_scene, seeds)
    hits, reports, found = pooled(with_nodules)
    assert reports >= 4 and found >= 6  # of 12 nodules
    assert binom.sf(hits - 1, reports, p_chance) < 1e-6  # far better than reports placed at random
    # The same participant on the same block with its nodules taken out, made to report three spots:
    # its reports no longer land on the nodule sites (they would if they came from the scene's truth).
    blank = _manual_trials(lambda o: _scene(o, nodules=[]), seeds, count=3)
    b_hits, b_reports, _ = pooled(blank)
    assert b_reports >= 8
    assert binom.sf(b_hits - 1, b_reports, p_chance) > 0.01
    assert b_hits / b_reports < 0.5 * hits / reports


# ------------------------------------------------------------------------------------------ the engine


def _seed003_protocol(tmp_path) -> str:
    """Seed 003's shipped protocol with a quicker virtual participant (a coarser survey), so that a whole
    session with three 1 kHz haptic trials stays a few seconds of computation."""
    doc = yaml.safe_load(find_shipped("protocols", "pseudo_haptic_palpation").read_text())
    doc["participants"]["virtual"]["params"] = {"line_spacing_mm": 16.0, "press_spacing_mm": 16.0,
                                                "follow_up_count": 3}
    path = tmp_path / "php_quick.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return str(path)


@pytest.mark.slow
def test_virtual_seed003_session_records_the_manual_trial_like_a_persons(tmp_path):
    folder = tmp_path / "php"
    init_workspace(folder, protocol=_seed003_protocol(tmp_path))
    with open_study(workspace=folder) as o:
        virtual = enroll(o.store, code="PHP-VVVVV")
        person = enroll(o.store, code="PHP-PPPPP")
        person_order = person.schedule.order
        result = run_session(o.store, virtual.code, virtual=True, seed=3)
        assert result.status == "completed" and result.trials_completed == 4
    # the same study's manual trial entered by a coordinator for a person (scripted), for the shape
    script = {
        "outcomes": [{"duration_s": 101.0, "reports": ["30 85", "60 35"], "note": "stopwatch"}],
        "trials": {i + 1: [{"t": 1.0, "request": "finish"}] for i, c in enumerate(person_order) if c != "manual"},
        "default_likert": 1,
    }
    answers = tmp_path / "answers.json"
    answers.write_text(json.dumps(script))
    assert main(["run", "--participant", person.code, "--input", str(answers), "--workspace", str(folder)]) == 0
    with open_study(workspace=folder) as o:
        trials = [t for t in o.store.list_trials() if t.condition == "manual"]
        assert len(trials) == 2
        by_session = {}
        for t in trials:
            events = o.store.events_frame(t.session_id, trial_id=t.id)
            reps = o.store.location_reports(t.id)
            assert all(r.t == pytest.approx(t.outcome["duration_s"]) for r in reps)  # indicated at the end
            by_session[t.session_id] = (t, events, [r.payload for r in reps], o.store.read_samples(t.id))
        (v, v_events, v_reports, v_samples), (p, p_events, p_reports, p_samples) = sorted(
            by_session.values(), key=lambda row: row[0].session_id)
        assert v.status == p.status == "completed"
        assert set(v.outcome) == set(p.outcome)  # the same outcome record
        assert v.outcome["ticks"] == p.outcome["ticks"] == 0 and v.outcome["scans"] == 0
        # no loop bookkeeping: the entry, and the phantom's truth the entry is scored against
        assert sorted(v_events.kind) == sorted(p_events.kind) == ["manual_outcome", "scene_truth"]
        v_truth, p_truth = (ev[ev.kind == "scene_truth"].payload.iloc[0] for ev in (v_events, p_events))
        assert set(v_truth) == set(p_truth) == {"nodules", "orientation_deg"} and len(p_truth["nodules"]) == 3
        v_entry, p_entry = (ev[ev.kind == "manual_outcome"].payload.iloc[0] for ev in (v_events, p_events))
        assert set(v_entry) == set(p_entry)
        assert p_entry["entered_by"] == "coordinator" and v_entry["entered_by"] == "simulated"
        assert "direct_touch" in v_entry["note"]
        assert v_samples.empty and p_samples.empty  # nothing is instrumented in a manual trial
        # reports are the participant's own, at the stopwatch time, in the person's report shape
        assert v_reports and all(set(r) == set(p_reports[0]) for r in v_reports)
        assert v.outcome["reports"] == len(v_reports) == v_entry["reports"]
        assert v.outcome["duration_s"] == pytest.approx(v_entry["duration_s"])
        assert 30.0 < v.outcome["duration_s"] < 1800.0 and p.outcome["duration_s"] == pytest.approx(101.0)
