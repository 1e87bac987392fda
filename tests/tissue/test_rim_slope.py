"""``rim_slope: physics_sign`` (off by default): the thickness_prior line held to the physics' sign. A thin layer
bonded to a rigid base feels firmer, never softer (Hayes et al. 1972), so a slope >= 0 learnt from a few noisy
practice presses is taken as 0 (the least-squares line with slope <= 0 is flat): no thickness correction."""

from __future__ import annotations

import numpy as np

from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.participants.tissue_rim import expected_firmness, learn_rim


def _presses(slope_per_mm: float, seed: int = 3):
    """16 plain presses at visible thickness 10-25 mm, log firmness on a line of ``slope_per_mm`` plus noise (SD
    0.11, the stylus presses' noise in the seed-12 practice)."""
    rng = np.random.default_rng(seed)
    h = np.linspace(10.0, 25.0, 16)
    values = np.exp(0.3 + slope_per_mm * h + rng.normal(0.0, 0.11, h.size))
    return [(values, "force")], np.ones(h.size, dtype=bool), h, values


def test_rim_slope_is_a_parameter_off_by_default():
    assert VirtualTissuePalpator({}).params["rim_slope"] == "as_learnt"
    assert VirtualTissuePalpator({"rim_slope": "physics_sign"}).params["rim_slope"] == "physics_sign"


def test_a_slope_of_the_wrong_sign_is_held_to_zero_and_corrects_nothing():
    cues, plain, h, values = _presses(+0.01)
    learnt = learn_rim(cues, plain, h)["force"]
    held = learn_rim(cues, plain, h, physics_sign=True)["force"]
    assert learnt["b_per_mm"] > 0  # the presses alone say thinner feels softer
    assert held["b_per_mm"] == 0.0 and held["b_fitted_per_mm"] == learnt["b_per_mm"]
    # the constrained least-squares line is flat at the mean log firmness: it expects the same everywhere
    assert np.allclose(expected_firmness(held, h), np.exp(np.mean(np.log(values))))
    assert held["n"] == learnt["n"] == 16


def test_a_slope_of_the_physics_sign_is_kept_as_learnt():
    cues, plain, h, _ = _presses(-0.012)
    assert learn_rim(cues, plain, h, physics_sign=True) == learn_rim(cues, plain, h)
    assert learn_rim(cues, plain, h)["force"]["b_per_mm"] < 0
