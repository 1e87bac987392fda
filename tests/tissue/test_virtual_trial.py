"""A whole virtual trial through the engine's trial loop: the virtual palpator finds nodules with force
feedback far more often than reports placed at random would."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from studyctl.controllers.tissue import StiffnessMapForceFeedback
from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.models.palpation_metrics import chance_hit_probability, score_trial
from studyctl.participants import (
    tissue_cue_learning,
    tissue_decision,
    tissue_hand,
    tissue_palpator,
    tissue_params,
    tissue_perception,
    tissue_questionnaire,
    tissue_slide,
)
from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes.tissue import StiffnessTissueScene


def test_the_palpator_never_sees_the_truth():
    # every module of the person but tissue_practice, whose practice blocks show the nodules on purpose
    for module in (tissue_palpator, tissue_hand, tissue_perception, tissue_decision, tissue_questionnaire,
                   tissue_params, tissue_slide, tissue_cue_learning):
        source = inspect.getsource(module)
        assert "truth" not in source.replace("Never the scene's truth", ""), module.__name__
    assert "scene" not in inspect.signature(VirtualTissuePalpator).parameters


@pytest.mark.slow
def test_force_feedback_trial_finds_nodules_better_than_chance():
    from scipy.stats import binom
    needs = StiffnessMapForceFeedback.needs({}) | {"view"}
    scene = StiffnessTissueScene.build({}, {"orientation_deg": 0}, needs, np.random.default_rng(0))
    controller = StiffnessMapForceFeedback({}, scene)
    device = SimulatedForceDevice({}, scene, np.random.default_rng(1))  # spring-held hand, Omni class
    device.open()
    # a person of seed 003's population (its trait locations): it compares each press with the tissue at the same
    # depth, so its depth judgement (read off the screen, 3 %) weighs about 1.7 times (the maps' force-depth
    # slope), and it holds a press until its judgement is that precise
    participant = VirtualTissuePalpator({"depth_weber": 0.03, "press_precision": 0.05, "line_spacing_mm": 9.5,
                                         "press_spacing_mm": 9.5, "z_threshold": 3.5, "report_fraction": 0.15})
    info = TrialInfo(condition="FF", time_limit_s=600.0, rate_hz=200.0, visual="realtime", public={})
    samples = []
    outcome = run_trial(
        info=info,
        controller=controller,
        device=device,
        participant=participant,
        clock=SimulatedClock(),
        rng=np.random.default_rng(10),
        view=scene.view,
        on_sample=lambda t, s: samples.append(s),
    )
    device.close()
    assert outcome.ended_by == "finish"
    assert participant.perceived["cues"] == ["force"]  # it felt forces; no cursor lag without PHF
    assert max(s["fz_n"] for s in samples) <= 3.3
    nodules = scene.truth()["nodules"]
    score = score_trial(outcome.reports, nodules, hit_radius_mm=10.0, duration_s=outcome.duration_s)
    p_chance = chance_hit_probability(nodules, 10.0, (0.0, 120.0, 0.0, 120.0))
    assert p_chance < 0.1
    assert score.reports >= 1 and score.nodules_found >= 1
    # one-sided binomial test of the hits against reports placed uniformly at random
    assert binom.sf(score.hits - 1, score.reports, p_chance) < 0.01
    assert score.ppv > 3 * p_chance
