"""A practice run of the virtual palpator on seed 000's example phantom, as the engine gives it, and a trial after it
(for the tests and scripts/palpation_practice_decision.py)."""

from __future__ import annotations

import numpy as np

from studyctl.devices.palpation import SimulatedPalpationDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.models.grid_cells import within_one_cell
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes.sponge import SpongePhantomScene

EXAMPLE = {"hard": 1, "medium": 2, "soft": 3}  # the engine's example phantom: the items at sites 1, 2, 3
SITES = ({"soft": 1, "medium": 3, "hard": 7}, {"soft": 5, "medium": 2, "hard": 4}, {"soft": 6, "medium": 7,
                                                                                         "hard": 1})


def found(out, scene):
    """Per tumour class: was a report within one cell of it (the paper's rule)?"""
    truth = scene.truth()["tumours"]
    return {t["class"]: any(within_one_cell((r["column"], r["row"]), (t["col"], t["row"])) for r in out.reports)
            for t in truth}


def practise(person, controller_cls, seed, marks=True, time_limit_s=300.0):
    """One practice run as the engine gives it: the example phantom, its marks in the public info, finish allowed,
    ``time_limit_s`` long at most (the protocol's 5 min)."""
    scene = SpongePhantomScene.build({}, {"sites": EXAMPLE}, frozenset({"view"}), np.random.default_rng(seed))
    device = SimulatedPalpationDevice({}, scene, np.random.default_rng(seed + 1))
    device.open()
    public = {**scene.public(), "practice": True, "requests": ["finish"]}
    if marks:
        public["marks"] = list(scene.marks())
    positions = []

    def spy(t, sample):
        positions.append((sample["probe_x_mm"], sample["probe_y_mm"], sample["depth_mm"]))

    out = run_trial(info=TrialInfo(controller_cls.name, time_limit_s, 50.0, public=public, visual="realtime"),
                    controller=controller_cls({}, scene), device=device, participant=person, clock=SimulatedClock(),
                    rng=np.random.default_rng(seed + 2), view=scene.view, on_sample=spy)
    device.close()
    return out, scene, positions


def trial_after_practice(person, controller_cls, k, after_practice=None, on_sample=None):
    """Trial ``k`` of the broken-controller checks: a person who familiarises practises first with the trial's
    controller (seed 100 + k), then palpates tumours at ``SITES[k % 3]`` with the camera view. ``after_practice``
    (optional) is called with the person and the example phantom between the practice and the trial; ``on_sample``
    (optional) gets the trial's samples as the engine logs them (t, sample)."""
    if person.practises:
        _, example, _ = practise(person, controller_cls, seed=100 + k)
        if after_practice is not None:
            after_practice(person, example)
    sites = SITES[k % len(SITES)]
    scene = SpongePhantomScene.build({}, {"sites": sites}, frozenset({"view"}), np.random.default_rng(k))
    device = SimulatedPalpationDevice({}, scene, np.random.default_rng(k + 1))
    device.open()
    out = run_trial(info=TrialInfo(controller_cls.name, 600.0, 50.0, public=dict(scene.public()), visual="realtime"),
                    controller=controller_cls({}, scene), device=device, participant=person,
                    clock=SimulatedClock(), rng=np.random.default_rng(k + 2), view=scene.view, on_sample=on_sample)
    device.close()
    return out, scene
