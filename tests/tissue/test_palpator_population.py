"""The tissue palpator's people: every parameter declared with its source, the shipped populations load,
traits change what a person does, and a broken controller is still noticed (force feedback that renders no
force loses its advantage, because the person feels nothing, not because anything reads the truth)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from studyctl import populations
from studyctl.controllers.tissue import StiffnessMapForceFeedback
from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.models.palpation_metrics import score_trial
from studyctl.participants.tissue_palpator import PARAMS, VirtualTissuePalpator
from studyctl.plugins.interfaces import TrialInfo
from studyctl.populations.loader import load_population_file
from studyctl.populations.targets import load_targets_file
from studyctl.scenes.tissue import StiffnessTissueScene

# a typical person of the shipped seed 002 population (its traits' locations)
PERSON_002 = {"tempo": 1.7, "line_spacing_mm": 12.0, "press_spacing_mm": 12.0, "margin_mm": 10.0,
              "z_threshold": 5.0, "report_fraction": 0.4}


def test_every_parameter_says_where_it_comes_from():
    for p in PARAMS:
        assert p.source.startswith(("CITED:", "CHOSEN:", "FITTED")), p.name


@pytest.mark.parametrize("protocol", ["data_driven_palpation", "pseudo_haptic_palpation"])
def test_shipped_populations_and_targets_load(protocol):
    folder = Path(populations.__file__).parent
    pop = load_population_file(folder / f"{protocol}.yaml")
    assert pop.name == protocol
    targets = load_targets_file(folder / f"{protocol}.targets.yaml")
    roles = [t.role for t in targets.targets]
    assert roles.count("validation") * 3 >= len(roles)  # at least a third kept out of the fit
    assert any(t.statistic == "verdict" and t.role == "validation" for t in targets.targets)


def _trial_002(params, *, seed, ff=None):
    """One seed 002 haptic trial through the trial loop; returns (score, participant)."""
    spec = {"phantom": "seed002_curved"}
    ff = ff or {}
    cparams = {"horizontal": "off", "release_on_retract": False, **ff}
    needs = StiffnessMapForceFeedback.needs(cparams) | {"view"}
    scene = StiffnessTissueScene.build(spec, {"orientation_deg": 0.0}, needs, np.random.default_rng(seed))
    device = SimulatedForceDevice({}, scene, np.random.default_rng(seed + 1))
    device.open()
    person = VirtualTissuePalpator(params)
    info = TrialInfo(condition="haptic", time_limit_s=600.0, rate_hz=250.0, visual="realtime",
                     public={**scene.public(), "trial_index": 1})
    out = run_trial(info=info, controller=StiffnessMapForceFeedback(cparams, scene), device=device,
                    participant=person, clock=SimulatedClock(), rng=np.random.default_rng(seed + 2), view=scene.view)
    device.close()
    assert out.ended_by == "finish"
    score = score_trial(out.reports, scene.truth()["nodules"], hit_radius_mm=10.0, duration_s=out.duration_s)
    return score, person


@pytest.mark.slow
def test_force_feedback_without_force_loses_its_advantage():
    working = [_trial_002(PERSON_002, seed=s)[0] for s in (11, 12)]
    broken = [_trial_002(PERSON_002, seed=s, ff={"max_force_n": 0.01})[0] for s in (11, 12)]
    # of 4: compared at like depths nodule A feels ~2.5 times as stiff as its surroundings, and this person reports
    # only spots at least 0.4 as clear as the clearest, so A is reported in both trials and B (0.4-0.6) may not be
    assert sum(sc.nodules_found for sc in working) >= 2
    assert sum(sc.nodules_found for sc in broken) == 0


@pytest.mark.slow
def test_a_quicker_person_finishes_sooner_on_the_same_trial():
    slow, slow_person = _trial_002({**PERSON_002, "tempo": 1.0}, seed=11)
    quick, quick_person = _trial_002({**PERSON_002, "tempo": 2.5}, seed=11)
    assert quick.detection_time_s < slow.detection_time_s
    # per press (moving, pressing, holding): the quicker person may re-palpate more spots in its trial
    per_press = [sc.detection_time_s / len(p._presses) for sc, p in ((slow, slow_person), (quick, quick_person))]
    assert per_press[1] < 0.75 * per_press[0]


def test_trial_tempo_varies_within_a_person_and_grows_with_practice():
    person = VirtualTissuePalpator({"tempo": 1.5, "tempo_trial_cv": 0.2, "practice_gain": 0.3})
    tempos = []
    for k in range(1, 41):
        info = TrialInfo(condition="FF", time_limit_s=10.0, rate_hz=250.0, visual="realtime",
                         public={"trial_index": k if k <= 20 else 1})
        person.begin_trial(info, np.random.default_rng(k))
        tempos.append(person._motor["tempo"])
    later, first = np.array(tempos[5:20]), np.array(tempos[20:])
    assert 0.1 < np.std(np.log(first)) < 0.35  # trial-to-trial noise of about the stated CV
    assert np.mean(later) > 1.15 * np.mean(first)  # practice: later trials quicker
    assert VirtualTissuePalpator({"tempo": 1.5})._trial_motor(info, np.random.default_rng(0))["tempo"] == 1.5


# a sharp-eyed person of the seed 003 population (its trait locations and fixed behaviour, visual_weber at the
# range's low end)
PERSON_003 = {"tempo": 2.16, "line_spacing_mm": 9.5, "press_spacing_mm": 9.5, "visual_weber": 0.02, "hand_weber": 0.0,
              "ratio_window_mm": 1.0, "z_threshold": 2.0, "report_fraction": 0.15, "press_precision": 0.048,
              "judge_from_bottom": True}


def _trial_003(params, *, seed, controller, cparams=None, person_cls=VirtualTissuePalpator):
    """One seed 003 trial (PHF or FF controller, block at 0°) through the trial loop; returns (score, person)."""
    from studyctl.controllers.tissue import PseudoHaptic, PseudoHapticForceFeedback

    cls = {"PHF": PseudoHaptic, "FF": StiffnessMapForceFeedback, "PHF_FF": PseudoHapticForceFeedback}[controller]
    cparams = cparams or {}
    needs = cls.needs(cparams) | {"view"}
    scene = StiffnessTissueScene.build({"phantom": "seed003_block"}, {"orientation_deg": 0.0}, needs,
                                       np.random.default_rng(seed))
    device = SimulatedForceDevice({}, scene, np.random.default_rng(seed + 1))
    device.open()
    person = person_cls(params)
    info = TrialInfo(condition=controller, time_limit_s=900.0, rate_hz=250.0, visual="realtime",
                     public={**scene.public(), "trial_index": 1})
    out = run_trial(info=info, controller=cls(cparams, scene), device=device, participant=person,
                    clock=SimulatedClock(), rng=np.random.default_rng(seed + 2), view=scene.view)
    device.close()
    assert out.ended_by == "finish"
    return score_trial(out.reports, scene.truth()["nodules"], hit_radius_mm=10.0, duration_s=out.duration_s), person


@pytest.mark.slow
def test_pseudo_haptics_that_never_slows_the_cursor_is_noticed():
    """PHF whose reduced ratio never applies (Δf_n must exceed 10 N): the cursor follows the hand as in the air,
    the person sees no resistance, uses no cursor cue and finds nothing."""
    working = [_trial_003(PERSON_003, seed=s, controller="PHF") for s in (11, 12)]
    broken = [_trial_003(PERSON_003, seed=s, controller="PHF", cparams={"delta_threshold_n": 10.0}) for s in (11, 12)]
    assert sum(sc.nodules_found for sc, _ in working) >= 2  # of 6
    assert all("cursor" in person.perceived["cues"] for _, person in working)
    assert sum(sc.nodules_found for sc, _ in broken) == 0
    assert all(person.perceived.get("cues", []) == [] for _, person in broken)


@pytest.mark.slow
def test_seed_003_force_feedback_without_force_is_noticed():
    working = _trial_003(PERSON_003, seed=11, controller="FF")[0]
    broken = _trial_003(PERSON_003, seed=11, controller="FF", cparams={"max_force_n": 0.01})[0]
    assert working.nodules_found >= 2
    assert broken.nodules_found == 0


class _PressClock(VirtualTissuePalpator):
    """Counts the time spent in one phase: pressing (from above the surface down to the wanted depth) here."""

    phase = "press"
    spent_s = 0.0

    def act(self, t, percept):
        if getattr(self, "_phase", None) == self.phase:
            self.spent_s += self._dt
        return super().act(t, percept)


class _DwellClock(_PressClock):
    """Counts the time spent at press bottoms (the dwell: settling and holding)."""

    phase = "dwell"


@pytest.mark.slow
def test_presses_under_both_feedbacks_keep_their_pace_once_adapted():
    """PHF+FF: the cursor yields (f + 1) times less than the hand and the hand is pushed back, so a press steered
    by the cursor crept to its depth; a person who adapts its pressing gain to that presses sooner, and still
    finds nodules."""
    # with the settling waited out before each hold (judge_from_bottom false), where the creep was measured; a
    # hold that runs from the bottom presses in 0.19 s either way at this seed, so it cannot show the adaptation
    slow = {**PERSON_003, "judge_from_bottom": False}
    crept, crept_person = _trial_003(slow, seed=11, controller="PHF_FF", person_cls=_PressClock)
    adapted, adapted_person = _trial_003({**slow, "press_adaptation": 0.3}, seed=11, controller="PHF_FF",
                                         person_cls=_PressClock)
    per_press = [p.spent_s / len(p._presses) for p in (crept_person, adapted_person)]
    assert per_press[1] < 0.85 * per_press[0], per_press
    assert adapted.nodules_found >= 1


@pytest.mark.slow
def test_a_hold_judged_from_the_press_bottom_does_not_wait_out_the_settling_first():
    """FF: the push chatters for ~0.4 s after each press reaches its depth (seed 003's release-on-retract). A
    person who gathers evidence from the bottom on holds no longer than its judgement needs; one who starts
    judging only once the push is steady adds the settling to every hold. Both still find nodules."""
    after, after_person = _trial_003({**PERSON_003, "judge_from_bottom": False}, seed=11, controller="FF",
                                     person_cls=_DwellClock)
    during, during_person = _trial_003(PERSON_003, seed=11, controller="FF", person_cls=_DwellClock)
    per_press = [p.spent_s / len(p._presses) for p in (after_person, during_person)]
    assert per_press[1] < 0.75 * per_press[0], per_press
    assert during.nodules_found >= 1


def test_a_press_steered_by_feel_takes_the_hands_travel_once_a_push_is_felt():
    """press_steer: felt: before any push the press is steered by the cursor; from the first push felt, by the
    cursor's depth then plus the hand's travel since (proprioception), so a cursor held back does not hold the press."""
    person = VirtualTissuePalpator({"press_steer": "felt"})
    person.begin_trial(TrialInfo(condition="PHF_FF", time_limit_s=10.0, rate_hz=250.0, visual="realtime", public={}),
                       np.random.default_rng(0))
    person._press = {}
    assert person._felt_depth((5.0, 6.0, 21.0), (5.0, 6.0, 17.0), 0.0) == (5.0, 6.0, 21.0)  # nothing felt yet
    assert person._felt_depth((5.0, 6.0, 20.5), (5.0, 6.0, 16.0), 0.3) == (5.0, 6.0, 20.5)  # the push is felt here
    # the hand goes 2 mm deeper while the cursor, slowed and ratcheted up by the on/off push, rises 0.4 mm
    assert person._felt_depth((5.0, 6.0, 20.9), (5.0, 6.0, 14.0), 0.0) == pytest.approx((5.0, 6.0, 18.5))
    assert VirtualTissuePalpator({})._steer_felt is False  # off by default: the cursor, as before


@pytest.mark.slow
def test_with_both_feedbacks_a_press_steered_by_feel_no_longer_waits_for_the_slowed_cursor():
    """PHF+FF: a press steered by the cursor waits for a cursor slowed by pseudo-haptics and lifted back by the
    release-on-retract push; steered by the hand's felt travel it is as quick as with force feedback alone. FF (the
    cursor follows the hand) is the same trial either way; a broken FF (no force) is still noticed."""
    person = {**PERSON_003, "press_adaptation": 0.3}
    seen, seen_p = _trial_003(person, seed=11, controller="PHF_FF", person_cls=_PressClock)
    felt, felt_p = _trial_003({**person, "press_steer": "felt"}, seed=11, controller="PHF_FF", person_cls=_PressClock)
    per_press = [p.spent_s / len(p._presses) for p in (seen_p, felt_p)]
    assert per_press[1] < 0.75 * per_press[0], per_press
    assert felt.detection_time_s < seen.detection_time_s
    assert felt.nodules_found >= 1
    ff = [_trial_003({**person, "press_steer": s}, seed=11, controller="FF")[0] for s in ("seen", "felt")]
    assert ff[0].detection_time_s == ff[1].detection_time_s and ff[0].report_hits == ff[1].report_hits
    broken = _trial_003({**person, "press_steer": "felt"}, seed=11, controller="FF", cparams={"max_force_n": 0.01})
    assert ff[1].nodules_found >= 2 and broken[0].nodules_found == 0
