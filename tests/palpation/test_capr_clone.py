"""A CAPR model is built once per process and parameter set and each bio-inspired controller steps its own clone:
the clone gives a fresh build's floats and shares no state with its template or other clones."""

from __future__ import annotations

import numpy as np
import pytest

from studyctl.controllers.bio_inspired import BioInspiredController
from studyctl.models import capr


@pytest.fixture(scope="module")
def pops():
    contact = capr.SkinContact(radius_mm=4.0)  # the bio-inspired controller's contact
    return [capr.build_population(t, contact) for t in capr.TYPES.values()]


def _forces(seed: int, ticks: int) -> np.ndarray:
    """Presses past F_crit (≈ 2.1 N: the deep path runs and rings down) and light touches, with sensor noise."""
    rng = np.random.default_rng(seed)
    f = []
    while len(f) < ticks:
        peak, rise, hold = rng.uniform(0.3, 5.0), rng.integers(3, 25), rng.integers(0, 30)
        f += list(np.linspace(0.02, peak, rise)) + [peak] * hold + list(np.linspace(peak, 0.02, rise)) + [0.02] * 10
    return np.asarray(f[:ticks]) + rng.normal(0.0, 0.01, ticks)


def _trace(model: capr.CaprModel, forces: np.ndarray) -> list[str]:
    return [repr((model.step(f), model.last_active)) for f in forces]


@pytest.mark.parametrize("compiled", [False, None])
def test_clones_step_as_fresh_builds_and_keep_their_own_state(pops, compiled):
    a, b = _forces(1, 600), _forces(2, 600)
    template = capr.CaprModel(pops, compiled=compiled)
    template.step(3.0)  # a used template: its state must not leak into a clone
    one, two = template.clone(), template.clone()
    got_one, got_two = [], []
    for fa, fb in zip(a, b, strict=True):  # interleaved: shared work buffers or state would mix the two traces
        got_one += _trace(one, [fa])
        got_two += _trace(two, [fb])
    assert got_one == _trace(capr.CaprModel(pops, compiled=compiled), a)
    assert got_two == _trace(capr.CaprModel(pops, compiled=compiled), b)


def test_controllers_share_one_built_model_and_step_their_own():
    first, second = BioInspiredController({}), BioInspiredController({})
    assert first.model is not second.model
    assert first.model._lin is second.model._lin  # built once
    other = BioInspiredController({"window_s": 0.1})
    assert other.model._lin is not first.model._lin  # another parameter set, another build
