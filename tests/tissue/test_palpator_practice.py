"""The tissue palpator's practice run with visible nodules (practice: learn, seed 003): it presses on and around
the marks it is shown and on plain tissue, learns from its own press records per cue what a press near a nodule
shows, weights its cues and tests re-palpated spots by that in the condition's test, keeps it across a resume, and
a broken controller is still noticed (practice through it teaches nothing)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from studyctl.errors import ModelParameterError
from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.participants.tissue_practice import near_marks, nodule_contrast, practice_points, trust
from studyctl.plugins.interfaces import TrialInfo
from studyctl.plugins.params import validate_params

MARKS = [{"name": "A", "x_mm": 30.0, "y_mm": 30.0, "diameter_mm": 10.0},
         {"name": "B", "x_mm": 90.0, "y_mm": 40.0, "diameter_mm": 8.0},
         {"name": "C", "x_mm": 60.0, "y_mm": 90.0, "diameter_mm": 6.0}]


def _practising(condition: str = "PHF_FF", **params) -> VirtualTissuePalpator:
    # every press within a baseline radius of some plain presses (the records below are sparse)
    person = VirtualTissuePalpator({"practice": "learn", "baseline_radius_mm": 40.0, **params})
    person.begin_trial(TrialInfo(condition=condition, time_limit_s=300.0, rate_hz=250.0, visual="realtime",
                                 public={"practice": True, "marks": MARKS}), np.random.default_rng(0))
    return person


def _records(force_excess: dict[str, float], cursor_excess: dict[str, float], rng) -> list[dict]:
    """Press records as the person's perception writes them: 4 near each mark (within 4 mm), 24 on plain tissue;
    the push felt per depth and the cursor's slowing raised near a mark by the given shares, with 2 % noise."""
    rows = []
    spots = [(m["name"], m["x_mm"] + dx, m["y_mm"] + dy) for m in MARKS
             for dx, dy in ((2.0, 0.0), (-2.0, 1.0), (0.0, -3.0), (1.0, 3.0))]
    spots += [("", x, y) for x in (10.0, 50.0, 70.0, 110.0) for y in (10.0, 60.0, 70.0, 110.0, 20.0, 80.0)]
    for name, x, y in spots:
        seen = 5.0 * (1.0 + 0.01 * rng.normal())
        felt = seen * 0.3 * (1.0 + force_excess.get(name, 0.0)) * (1.0 + 0.02 * rng.normal())
        ratio = 1.5 * (1.0 + cursor_excess.get(name, 0.0)) * (1.0 + 0.02 * rng.normal())
        rows.append({"x": x, "y": y, "force": felt / seen, "felt": felt, "seen": seen, "ratio": ratio,
                     "ratio_seen": seen, "stage": "practice"})
    return rows


def test_practice_is_a_parameter_off_by_default_and_needs_marks():
    assert VirtualTissuePalpator({}).practises is False
    assert VirtualTissuePalpator({"practice": "learn"}).practises is True
    with pytest.raises(ModelParameterError, match="practice"):
        validate_params("virtual_tissue_palpator participant", {"practice": "watch"}, VirtualTissuePalpator.PARAMS)
    person = _practising()
    person.info = TrialInfo(condition="PHF_FF", time_limit_s=300.0, rate_hz=250.0, visual="realtime",
                            public={"practice": True, "marks": []})
    person._marks = []
    surface = {"xs_mm": [0.0, 60.0, 120.0], "ys_mm": [0.0, 60.0, 120.0], "heights_mm": [[25.0] * 3] * 3}
    with pytest.raises(ModelParameterError, match="visible nodules"):
        person._setup(surface)


def test_a_test_trial_is_never_a_practice_even_with_marks_in_view():
    """Marks reach the person only with the practice flag (the engine shows them only then): a test trial's
    info never makes a practice, and a person without practice: learn ignores a practice's marks."""
    person = VirtualTissuePalpator({"practice": "learn"})
    person.begin_trial(TrialInfo(condition="FF", time_limit_s=900.0, rate_hz=250.0, visual="realtime",
                                 public={"marks": MARKS}), np.random.default_rng(0))
    assert person._marks is None
    untaught = VirtualTissuePalpator({})
    untaught.begin_trial(TrialInfo(condition="FF", time_limit_s=300.0, rate_hz=250.0, visual="realtime",
                                   public={"practice": True, "marks": MARKS}), np.random.default_rng(0))
    assert untaught._marks is None


def test_practice_presses_go_near_each_mark_and_on_plain_tissue_clear_of_all():
    lattice = [(float(x), float(y)) for x in np.arange(6.0, 115.0, 9.5) for y in np.arange(6.0, 115.0, 9.5)]
    pts = practice_points(lattice, MARKS, 4, 9.5, 10.0, lambda x, y: 0 <= x <= 120 and 0 <= y <= 120,
                          np.random.default_rng(3))
    arr = np.array(pts)
    mark = near_marks(arr, MARKS, 4.75)
    assert [int((mark == i).sum()) for i in range(3)] == [4, 4, 4]
    plain = arr[mark < 0]
    assert len(plain) == 24
    for m in MARKS:
        assert np.hypot(plain[:, 0] - m["x_mm"], plain[:, 1] - m["y_mm"]).min() >= m["diameter_mm"] / 2 + 10.0
    assert pts == sorted(pts, key=lambda p: (p[1], p[0]))  # along the lines


def test_practice_learns_each_cue_from_its_own_records_and_weights_the_cue_that_showed_the_nodules():
    rng = np.random.default_rng(5)
    # the push rose 20-30 % near the marks, the cursor's slowing not at all
    felt = _practising()
    felt._presses = _records({"A": 0.3, "B": 0.25, "C": 0.2}, {}, rng)
    assert felt._decide() == []  # nothing reported in practice
    learnt = felt.learnt["PHF_FF"]
    assert learnt["force"]["excess"] == pytest.approx(0.25, abs=0.03)
    assert learnt["force"]["faintest"] == pytest.approx(0.2, abs=0.03)
    assert learnt["force"]["n"] == 12 and learnt["cursor"]["n"] == 12
    assert abs(learnt["cursor"]["excess"]) < 0.03
    w = trust(learnt)
    assert w["force"] == 1.0 and w["cursor"] < 0.15
    # the other way round: the cursor showed the nodules, the push did not
    seen = _practising()
    seen._presses = _records({}, {"A": 0.3, "B": 0.25, "C": 0.2}, np.random.default_rng(5))
    seen._decide()
    w2 = trust(seen.learnt["PHF_FF"])
    assert w2["cursor"] == 1.0 and w2["force"] < 0.15


def test_what_practice_taught_applies_to_that_conditions_test_only_and_survives_a_resume():
    person = _practising(force_trust=1.0, cursor_trust=0.8)
    person._presses = _records({"A": 0.3, "B": 0.25, "C": 0.2}, {}, np.random.default_rng(5))
    person._decide()
    test = TrialInfo(condition="PHF_FF", time_limit_s=900.0, rate_hz=250.0, visual="realtime", public={})
    person.begin_trial(test, np.random.default_rng(1))
    taught, was_taught = person._trust()
    assert was_taught
    assert taught["force"] == 1.0 and taught["cursor"] < 0.15  # not the untaught 0.8
    person.begin_trial(TrialInfo(condition="PHF", time_limit_s=900.0, rate_hz=250.0, visual="realtime", public={}),
                       np.random.default_rng(1))
    assert person._trust() == ({"force": 1.0, "cursor": 0.8}, False)  # PHF was not practised: untaught
    # memory -> JSON (the session store) -> a new process's person: the same weights and the same test alternative
    memory = json.loads(json.dumps(person.memory()))
    resumed = VirtualTissuePalpator({"practice": "learn", "baseline_radius_mm": 40.0, "force_trust": 1.0,
                                     "cursor_trust": 0.8})
    resumed.recall(memory)
    resumed.begin_trial(test, np.random.default_rng(1))
    person.begin_trial(test, np.random.default_rng(1))
    assert resumed._trust() == person._trust()
    assert nodule_contrast(resumed.learnt["PHF_FF"]) == nodule_contrast(person.learnt["PHF_FF"])
    assert VirtualTissuePalpator({}).memory() == {}  # an unpractised person's stored record is as before


@pytest.mark.slow
def test_practice_through_the_trial_loop_learns_the_push_and_a_broken_ff_teaches_nothing():
    """FF practice block (its nodules as the scene's marks) then an FF test trial (tests/tissue/
    test_palpator_population's, on a block of its own; no position from practice is ever used), through the scene,
    the simulated device and the controller: the working controller's push near the marks stands out; with FF
    rendering at most 0.01 N the person feels nothing in practice, learns no cue and still finds nothing."""
    from tissue.test_palpator_population import PERSON_003, _trial_003

    from studyctl.controllers.tissue import StiffnessMapForceFeedback
    from studyctl.devices.force3d import SimulatedForceDevice
    from studyctl.engine.clock import SimulatedClock
    from studyctl.engine.trial_loop import run_trial
    from studyctl.scenes.tissue import StiffnessTissueScene

    def practise(person, cparams):
        scene = StiffnessTissueScene.build({"phantom": "seed003_block"}, {"orientation_deg": 0.0},
                                           StiffnessMapForceFeedback.needs(cparams) | {"view"},
                                           np.random.default_rng(7))
        device = SimulatedForceDevice({}, scene, np.random.default_rng(8))
        device.open()
        info = TrialInfo(condition="FF", time_limit_s=300.0, rate_hz=250.0, visual="realtime",
                         public={**scene.public(), "practice": True, "marks": list(scene.marks())})
        out = run_trial(info=info, controller=StiffnessMapForceFeedback(cparams, scene), device=device,
                        participant=person, clock=SimulatedClock(), rng=np.random.default_rng(9), view=scene.view)
        device.close()
        assert out.ended_by == "finish" and out.reports == []
        return out

    class Practised(VirtualTissuePalpator):
        def __init__(self, params, cparams=None):
            super().__init__({**params, "practice": "learn"})
            practise(self, cparams or {})

    working = Practised(PERSON_003)
    learnt = working.learnt["FF"]["force"]
    assert learnt["n"] == 12 and learnt["excess"] / learnt["sd"] > 2.0  # a press near a nodule stands out
    assert math.isfinite(nodule_contrast(working.learnt["FF"]))

    broken_cp = {"max_force_n": 0.01}
    score, person = _trial_003(PERSON_003, seed=11, controller="FF", cparams=broken_cp,
                               person_cls=lambda p: Practised(p, broken_cp))
    assert person.learnt["FF"] == {}  # nothing felt in practice: nothing learnt
    assert score.nodules_found == 0
    ok, _ = _trial_003(PERSON_003, seed=11, controller="FF", person_cls=lambda p: Practised(p))
    assert ok.nodules_found >= 2
