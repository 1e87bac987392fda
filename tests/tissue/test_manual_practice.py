"""Seed 002's manual practice (``manual_practice: transparent``, off by default): "Before the manual palpation
experiment, participants were asked to do a practice trial run palpating a transparent silicone phantom tissue with
and without nodules inside" (§V). The engine runs a manual condition's familiarisation as a practice block for a
virtual person who asks for it: the bare finger on the example phantom, its nodules seen (the scene's marks). What
the person learns there (``thickness_prior``) applies to the manual test; the practice is not trial time."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from studyctl.devices.direct_touch import DirectTouchDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.models.palpation_metrics import score_trial
from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes.tissue import StiffnessTissueScene

# a person of the shipped seed 002 population (v3) who made a manual corner report at seed 2024 (DDP-V010's traits)
PERSON_V010 = {"force_weber": 0.0648, "line_spacing_mm": 12.18, "margin_mm": 7.6, "press_spacing_mm": 11.6,
               "report_fraction": 0.278, "tempo": 1.47, "z_threshold": 3.41, "max_reports": 3}


def _manual_002(person: VirtualTissuePalpator, *, seed: int, practice: bool = False):
    """One seed 002 manual trial (or its practice block: the nodules shown as marks) with the simulated bare finger
    on the phantom; returns (score or None, outcome)."""
    scene = StiffnessTissueScene.build({"phantom": "seed002_curved"}, {"orientation_deg": 0.0}, frozenset(),
                                       np.random.default_rng(seed))
    finger = DirectTouchDevice({}, scene)
    finger.open()
    public = {**scene.public(), "trial_index": 1}
    if practice:
        public.update(practice=True, marks=list(scene.marks()), requests=["finish"])
    info = TrialInfo(condition="manual", time_limit_s=600.0, rate_hz=50.0, visual=None, public=public)
    out = run_trial(info=info, controller=None, device=finger, participant=person, clock=SimulatedClock(),
                    rng=np.random.default_rng(seed + 2))
    finger.close()
    assert out.ended_by == "finish"
    if practice:
        return None, out
    return score_trial(out.reports, scene.truth()["nodules"], hit_radius_mm=10.0, duration_s=out.duration_s), out


def test_manual_practice_is_a_parameter_off_by_default():
    assert VirtualTissuePalpator({}).practises_manual is False
    assert VirtualTissuePalpator({"manual_practice": "transparent"}).practises_manual is True
    # asking only for the manual practice adds no practice block to the feedback conditions
    assert VirtualTissuePalpator({"manual_practice": "transparent"}).practises is False


@pytest.mark.slow
def test_after_the_transparent_practice_the_bare_finger_leaves_the_thin_corner_unreported():
    # Without practice this person's manual trial (seed 12) reports both nodules and a third spot at the corner
    # (4, 4), where the slab is thinnest and presses firmest. After the practice block (bare finger, nodules seen)
    # it has learnt from its plain presses how much firmer the tissue feels where it looks thinner (thickness_prior:
    # learn) and judges the corner against that: both nodules, no false report.
    old, _ = _manual_002(VirtualTissuePalpator(PERSON_V010), seed=12)
    learner = VirtualTissuePalpator({**PERSON_V010, "thickness_prior": "learn", "manual_practice": "transparent"})
    _, practice = _manual_002(learner, seed=112, practice=True)
    new, _ = _manual_002(learner, seed=12)
    assert practice.reports == []  # a practice names no spot
    assert learner.rim_learnt["manual"]["force"]["b_per_mm"] < 0  # thinner looks firmer, felt by the bare finger
    assert (old.nodules_found, old.false_reports) == (2, 1)
    assert (new.nodules_found, new.false_reports) == (2, 0)


V4_SWITCHES = ("  thickness_prior: learn\n", "  rim_slope: physics_sign\n", "  manual_practice: transparent\n")


def _population(tmp_path, name: str, fixed: str):
    from studyctl.populations import load_population_file, shipped_population_path

    text = shipped_population_path("data_driven_palpation").read_text()
    assert "fixed:\n" in text
    # v4 ships the manual practice and the rim prior; take them out to get v3's people, then add ``fixed``
    for line in V4_SWITCHES:
        assert line in text
        text = text.replace(line, "")
    path = tmp_path / f"{name}.yaml"
    path.write_text(text.replace("fixed:\n", "fixed:\n" + fixed))
    return load_population_file(path)


def _session(tmp_path, name: str, fixed: str):
    """One virtual person of v3 (plus ``fixed`` lines) through a whole seed 002 session (the 1 kHz controller run at
    250 Hz); returns (the manual trial's duration and reports, practice loops run, the person's last memory)."""
    from studyctl.engine.recorder import MEMORY_EVENT
    from studyctl.store.workspace import open_study
    from studyctl.workflows.simulate import simulate_study

    result = simulate_study("data_driven_palpation", 1, 5, tmp_path / name, sim_rate_hz=250.0,
                            population=_population(tmp_path, name, fixed))
    with open_study(workspace=result.workspace) as o:
        person = o.store.list_participants(o.study.id)[0]
        events = o.store.events_frame(o.store.list_sessions(person.id)[0].id)
    con = sqlite3.connect(result.database)
    manual = con.execute("select json_extract(outcome, '$.duration_s'), json_extract(outcome, '$.reports') "
                         "from trial where condition = 'manual'").fetchall()
    con.close()
    memory = events[events.kind == MEMORY_EVENT].payload
    return manual, int((events.kind == "practice_trial_loop_end").sum()), (memory.iloc[-1]["memory"]
                                                                           if len(memory) else {})


@pytest.mark.slow
def test_the_engine_runs_the_manual_practice_for_a_virtual_person_who_asks_and_it_is_not_trial_time(tmp_path):
    """v3 runs no practice at all. With manual_practice alone the engine runs the manual condition's practice (bare
    finger, nodules seen) and nothing is learnt there, so the manual trial is the same trial: same duration, same
    reports (its own random streams; the practice's minutes are the familiarisation's, not the trial's). With the
    thickness prior too, both conditions are practised and the person keeps a line for each."""
    base, base_loops, base_memory = _session(tmp_path, "v3", "")
    alone, alone_loops, _ = _session(tmp_path, "manual", "  manual_practice: transparent\n")
    both, both_loops, both_memory = _session(tmp_path, "both", "  manual_practice: transparent\n"
                                                               "  thickness_prior: learn\n")
    assert (base_loops, alone_loops, both_loops) == (0, 1, 2)
    assert alone == base and len(base) == 1
    assert base_memory == {}
    assert set(both_memory["thickness_prior"]) == {"manual", "haptic"}
    assert both_memory["thickness_prior"]["manual"]["force"]["n"] >= 5
