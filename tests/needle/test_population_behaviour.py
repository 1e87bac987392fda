"""The shipped needle population through the real controller, device and scene: people differ, traits act on
what they sense, and a broken controller is still noticed (ESG given BL physics loses its advantage)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from needle_helpers import condition_params

from studyctl.controllers.needle import NeedleHybridController
from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.models.needle_metrics import needle_trial_metrics
from studyctl.participants.needle_operator import PARAMS, VirtualNeedleOperator
from studyctl.plugins.interfaces import TrialInfo
from studyctl.populations import load_population_file, shipped_population_path
from studyctl.scenes.needle_liver import NeedleLiverScene


def _people(n: int, seed: int) -> list[dict]:
    path = shipped_population_path("needle_insertion")
    assert path is not None
    pop = load_population_file(path)
    rng = np.random.default_rng(seed)
    return [pop.params(pop.draw(rng)) for _ in range(n)]


def _run(label: str, physics: str, person: dict, sites: list[int], seed: int) -> list[tuple[int, float]]:
    """Three trials of one scenario as the person sees it (``label``), rendered with ``physics``."""
    op = VirtualNeedleOperator(person)
    out = []
    for k, site in enumerate(sites):
        rng = np.random.default_rng([seed, k])
        scene = NeedleLiverScene.build({}, {"sites": {"tumour": site}}, frozenset({"layers", "view"}), rng)
        ctrl = NeedleHybridController(condition_params(physics), scene)
        dev = SimulatedForceDevice({"device_class": "omega6"}, scene)
        dev.open()
        rows: list[tuple[float, float, float, float]] = []
        res = run_trial(info=TrialInfo(label, 90.0, 1000.0, "on_request"), controller=ctrl, device=dev,
                        participant=op, clock=SimulatedClock(), rng=rng,
                        on_sample=lambda t, s, rows=rows: rows.append((t, s["x_mm"], s["y_mm"], s["z_mm"])),
                        view=scene.view)
        m = needle_trial_metrics(pd.DataFrame(rows, columns=["t", "x_mm", "y_mm", "z_mm"]), res.events, scene.truth())
        out.append((m.scans, m.duration_s))
    return out


def test_population_people_differ_and_stay_in_the_declared_ranges():
    people = _people(12, 3)
    declared = {p.name: p for p in PARAMS}
    for name in ("insert_speed_mm_s", "scan_read_s", "force_weber", "recheck_mm", "cue_trust_rate"):
        values = [p[name] for p in people]
        assert np.std(values) > 0.05 * np.median(values)  # a trait, not a constant
        assert all(declared[name].low <= v <= declared[name].high for v in values)


@pytest.mark.slow  # 24 whole needle trials each: ~45 s in the loaded fast run
@pytest.mark.parametrize("label", ["ESG", "ES"])
def test_with_bl_physics_the_enhanced_scenario_loses_its_advantage(label):
    """The same people told 'ESG' (or 'ES') but given BL physics (a broken controller) need more time and scans. ES
    too, since what a person does with a trusted cue (cue_learn_late, cue_reach) acts only on a cue it felt: given
    BL physics, time ratio ESG 0.607, ES 0.799 with v6 and 0.748 with cue_learn_late + cue_reach (session 33)."""
    people = _people(4, 11)
    sites = [[2, 5, 9], [4, 7, 11], [1, 6, 10], [3, 8, 12]]
    real, broken = [], []
    for i, person in enumerate(people):
        real += _run(label, label, person, sites[i], seed=100 + i)
        broken += _run(label, "BL", person, sites[i], seed=100 + i)
    real_scans, real_time = np.mean([r[0] for r in real]), np.mean([r[1] for r in real])
    broken_scans, broken_time = np.mean([r[0] for r in broken]), np.mean([r[1] for r in broken])
    assert real_time < 0.92 * broken_time  # same people, same trial streams: only the physics differs
    assert real_scans < broken_scans


def _first_trial(label: str, person: dict) -> VirtualNeedleOperator:
    """One person's first trial of a scenario, through the real controller, device and scene."""
    op = VirtualNeedleOperator(person)
    rng = np.random.default_rng([5, 0])
    scene = NeedleLiverScene.build({}, {"sites": {"tumour": 2}}, frozenset({"layers", "view"}), rng)
    ctrl = NeedleHybridController(condition_params(label), scene)
    dev = SimulatedForceDevice({"device_class": "omega6"}, scene)
    dev.open()
    run_trial(info=TrialInfo(label, 90.0, 1000.0, "on_request"), controller=ctrl, device=dev, participant=op,
              clock=SimulatedClock(), rng=rng, on_sample=lambda t, s: None, view=scene.view)
    return op


@pytest.mark.slow  # 5 whole needle trials per reaching speed
@pytest.mark.parametrize("approach_speed_ratio", [2.5, 3.0, 4.0])
def test_a_sideways_probe_finds_the_stiff_channel_and_not_the_compliant_one(approach_speed_ratio):
    """A steady hand stays inside the guidance's 1 mm tolerance and never feels EG's channel; pushing sideways
    over the incision (probe_mm), it feels EG's 1000 N/m as a firm wall, and BL's 100 N/m not, whatever its
    reaching speed: it judges stiffness only from its slow probe (out and back) and in tissue, never while reaching
    onto the incision, where the channel's damper pushes back whatever the stiffness (with the probe coming back
    at reaching speed, a ratio of 3.0 made this person read BL's channel as a ~1000 N/m wall)."""
    steady = {**_people(1, 3)[0], "motor_noise_mm": 0.1, "approach_speed_ratio": approach_speed_ratio}
    assert "EG" not in _first_trial("EG", {**steady, "probe_mm": 0.0}).wall_k  # never felt
    probed = _first_trial("EG", {**steady, "probe_mm": 2.5})
    assert probed.wall_k["EG"] > 400.0 and probed.trust_guide["EG"] > 0.0 and probed.s.guided
    assert probed.memory()["probed"] == ["EG"]  # once per scenario, remembered across a resume
    again = VirtualNeedleOperator({**steady, "probe_mm": 2.5})
    again.recall(probed.memory())
    assert again.probed == {"EG"}
    assert "BL" not in _first_trial("BL", {**steady, "probe_mm": 2.5}).wall_k
