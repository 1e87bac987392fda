"""A practice run of the virtual palpator on seed 000's example phantom, as the engine gives it (for the tests)."""

from __future__ import annotations

import numpy as np

from studyctl.devices.palpation import SimulatedPalpationDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes.sponge import SpongePhantomScene

EXAMPLE = {"hard": 1, "medium": 2, "soft": 3}  # the engine's example phantom: the items at sites 1, 2, 3


def practise(person, controller_cls, seed, marks=True):
    """One practice run as the engine gives it: the example phantom, its marks in the public info, finish allowed."""
    scene = SpongePhantomScene.build({}, {"sites": EXAMPLE}, frozenset({"view"}), np.random.default_rng(seed))
    device = SimulatedPalpationDevice({}, scene, np.random.default_rng(seed + 1))
    device.open()
    public = {**scene.public(), "practice": True, "requests": ["finish"]}
    if marks:
        public["marks"] = list(scene.marks())
    positions = []

    def spy(t, sample):
        positions.append((sample["probe_x_mm"], sample["probe_y_mm"], sample["depth_mm"]))

    out = run_trial(info=TrialInfo(controller_cls.name, 300.0, 50.0, public=public, visual="realtime"),
                    controller=controller_cls({}, scene), device=device, participant=person, clock=SimulatedClock(),
                    rng=np.random.default_rng(seed + 2), view=scene.view, on_sample=spy)
    device.close()
    return out, scene, positions
