"""When the seed-000 palpator stops sampling: re-probing a cell whose evidence is already past a bound (``sure_odds``)
and lifting a press while a felt cue still rises (``lift_rule: settled``). Both are off by default."""

from __future__ import annotations

import math

import numpy as np
import pytest
from palpation.practice_support import found, trial_after_practice

from studyctl.controllers.palpation import LinearController, NoFeedback
from studyctl.devices.palpation import SimulatedPalpationDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.errors import ModelParameterError
from studyctl.participants.palpator import VirtualPalpator
from studyctl.participants.palpator_perception import _CellEvidence
from studyctl.participants.palpator_practice import CueWeights
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes.sponge import SpongePhantomScene

# one learnt cue, plain sponge at 0 with spread 1, one practice press on a mark 2 spreads off, 3 marks of 49 cells
CUES = CueWeights((("balloon_psi", "peak"),), (1.0,), (0.0,), 1.0, 2.0, 3 / 49)


def _queued_after_sweep(sure_odds: float, first_presses: list[float], cues: CueWeights = CUES,
                        **extra: float) -> set[tuple[int, int]]:
    """The cells a practised person re-probes after a sweep whose first presses gave this combined evidence."""
    person = VirtualPalpator({"report_rule": "odds", "sure_odds": sure_odds, "confirm_presses": 1, **extra})
    grid = {"columns": len(first_presses), "rows": 1, "cell_mm": 20.0}
    person.begin_trial(TrialInfo("linear", 600.0, 50.0, public={"grid": grid}), np.random.default_rng(0))
    person.cues = cues
    person.evidence = {(c, 1): _CellEvidence(combined=[v], presses=1) for c, v in enumerate(first_presses, 1)}
    swept = len(person._plan)  # the sweep queued at the start of the trial
    person._queue_confirmations(first=True)
    return {seg.cell for seg in person._plan[swept:] if seg.kind == "press"}


def test_a_cell_already_past_the_bound_is_not_reprobed():
    """Report level for one press at separation 2: 2/2 + ln(46/3)/2 = 2.37 spreads; at odds 19: 3.84. Sweep
    evidence 0 (plain), 2.2 (screened, undecided), 3.0 (past the report level) and 5.0 (past both)."""
    first = [0.0, 0.0, 0.0, 0.0, 2.2, 3.0, 5.0]
    assert _queued_after_sweep(0.0, first) == {(5, 1), (6, 1), (7, 1)}  # as before: every screened cell
    assert _queued_after_sweep(1.0, first) == {(5, 1)}  # only the undecided one
    assert _queued_after_sweep(19.0, first) == {(5, 1), (6, 1)}  # 3.0 is not sure enough at odds 19
    person = VirtualPalpator({"report_rule": "odds"})
    ev = _CellEvidence(combined=[0.0])
    person.cues = CUES
    assert person._level(ev) == pytest.approx(1 + math.log(46 / 3) / 2)
    assert person._level(ev, 19.0) == pytest.approx(1 + math.log(19 * 46 / 3) / 2)
    # without the odds rule there is no such bound: nothing is skipped
    assert VirtualPalpator({"report_rule": "z"})._level(ev, 19.0) == math.inf


def test_with_dismiss_odds_a_cell_is_dropped_only_below_the_lower_bound_of_the_sequential_test():
    """Wald's lower bound at odds 1/19 for one press at separation 2: 1 + ln(46 / 3 / 19) / 2 = 0.89 spreads (the
    fixed screen_z is 2); at separation 1 (a feedback whose practice told tumours apart less well) 0.5 + ln(0.81) =
    0.29, so more cells stay undecided. The upper bound (sure_odds 19: 3.84 at separation 2) still skips 5.0."""
    first = [0.0] * 6 + [0.5, 1.2, 2.2, 3.0, 5.0]  # plain sponge's level (the median) is 0
    assert _queued_after_sweep(19.0, first) == {(9, 1), (10, 1)}  # as before: screen_z 2
    assert _queued_after_sweep(19.0, first, dismiss_odds=1 / 19) == {(8, 1), (9, 1), (10, 1)}
    weak = CueWeights(CUES.keys, CUES.weights, CUES.centres, 1.0, 1.0, 3 / 49)  # sure bound 0.5 + ln(19 x 46/3)
    assert _queued_after_sweep(19.0, first, weak, dismiss_odds=1 / 19) == {(7, 1), (8, 1), (9, 1), (10, 1), (11, 1)}
    person = VirtualPalpator({"report_rule": "odds", "dismiss_odds": 1 / 19})
    person.cues = CUES
    assert person._screen(_CellEvidence(combined=[0.0])) == pytest.approx(1 + math.log(46 / 3 / 19) / 2)
    # without the odds rule (or before practice) screen_z stays the bar
    assert VirtualPalpator({"report_rule": "z", "dismiss_odds": 1 / 19})._screen(_CellEvidence()) == 2.0


def test_sure_odds_below_one_is_refused():
    with pytest.raises(ModelParameterError, match="sure_odds 0.5 must be 0 .off. or at least 1"):
        VirtualPalpator({"sure_odds": 0.5})
    with pytest.raises(ModelParameterError, match="lift_rule"):
        VirtualPalpator({"lift_rule": "rate"})


def _trial(controller_cls, params):
    scene = SpongePhantomScene.build({}, {"sites": {"soft": 1, "medium": 3, "hard": 7}}, frozenset(),
                                     np.random.default_rng(4))
    device = SimulatedPalpationDevice({}, scene, np.random.default_rng(5))
    device.open()
    person = VirtualPalpator({"rows": 2, "hold_s": 0.1, **params})
    samples = []
    public = {**scene.public(), "grid": {**scene.public()["grid"], "rows": 2}}
    out = run_trial(info=TrialInfo(controller_cls.name, 600.0, 50.0, public=public),
                    controller=controller_cls({}, scene), device=device, participant=person, clock=SimulatedClock(),
                    rng=np.random.default_rng(6), on_sample=lambda t, s: samples.append((t, s["force_n"])))
    device.close()
    return out, np.array(samples)


def _contact_s(samples: np.ndarray) -> float:
    return float(np.sum(samples[:, 1] > 0.5) * 0.02)


def test_a_press_is_held_while_the_balloon_still_fills():
    """Linear feedback: the balloon lags the force (pneumatic fill), so at the end of the planned hold the felt
    pressure is still rising and a person who lifts once it has settled holds longer, never more than
    settle_max_s a press. With no feedback nothing is felt and the rule changes nothing, sample for sample."""
    _, planned = _trial(LinearController, {})
    _, settled = _trial(LinearController, {"lift_rule": "settled"})
    _, capped = _trial(LinearController, {"lift_rule": "settled", "settle_max_s": 0.0})
    presses = 14 + 1  # 2 x 7 cells swept (and at least one re-probe)
    assert _contact_s(settled) > _contact_s(planned) + 0.04 * presses
    assert _contact_s(settled) < _contact_s(planned) + 1.0 * 3 * presses  # bounded (re-probes included)
    assert np.array_equal(capped, planned)
    _, none_planned = _trial(NoFeedback, {})
    _, none_settled = _trial(NoFeedback, {"lift_rule": "settled"})
    assert np.array_equal(none_planned, none_settled)


@pytest.mark.slow
@pytest.mark.parametrize("extra", [{"sure_odds": 19.0}, {"lift_rule": "settled"},
                                   {"sure_odds": 19.0, "dismiss_odds": 1 / 19}])
def test_with_either_stopping_rule_a_broken_controller_is_still_noticed(extra):
    """`none` in place of the bio-inspired controller, the shipped population's typical person with the rule on,
    24 trials each on the broken-controller test's tumours and seeds: fewer tumours found (measured with
    scripts/palpation_contact_time.py: sure_odds 19 41 vs 29, settled 34 vs 29 of 72)."""
    from studyctl.controllers.bio_inspired import BioInspiredController
    from studyctl.populations import load_population_file, shipped_population_path

    pop = load_population_file(shipped_population_path("bio_inspired_palpation"))
    params = {**pop.params({t.name: t.value(0.0) for t in pop.traits}), **extra}
    counts = {}
    for controller_cls in (BioInspiredController, NoFeedback):
        runs = (trial_after_practice(VirtualPalpator(params), controller_cls, k) for k in range(24))
        counts[controller_cls.name] = sum(sum(found(out, scene).values()) for out, scene in runs)
    assert counts["bio_inspired"] >= counts["none"] + 5, counts


def test_a_practised_person_keeps_the_usual_feel_that_stop_ratio_compares_with():
    """stop_ratio stops a press on a feel well above the running median of this trial's unstopped presses. A
    practised person (learnt cues set) keeps that median too, and a press already stopped does not enter it."""
    from studyctl.participants.palpator_press import _Segment

    person = VirtualPalpator({"stop_ratio": 1.6, "report_rule": "odds"})
    grid = {"columns": 7, "rows": 1, "cell_mm": 20.0}
    person.begin_trial(TrialInfo("linear", 600.0, 50.0, public={"grid": grid}), np.random.default_rng(0))
    person.cues = CUES  # as after the condition's practice
    for i, peak in enumerate((10.0, 11.0, 40.0, 12.0, 13.0, 14.0)):
        person._notes = {("balloon_psi", "peak"): peak, ("vibration_ms2", "peak"): 2.0}
        stopped = peak == 40.0  # a press the feedback already stopped: not what plain pressing feels like
        person._end_segment(_Segment("press", 1.0, (0.0, 0.0, 0.0), (0.0, 0.0, 3.0), cell=(i + 1, 1), intended=3.0,
                                     stopped=stopped))
    assert person._usual["balloon_psi"] == pytest.approx(12.0)
    assert person._strong({"balloon_psi": 1.6 * 12.0 + 0.1})
    assert not person._strong({"balloon_psi": 1.6 * 12.0 - 0.1})


def test_stop_match_depth_compares_a_checkpoint_with_plain_tissue_at_the_same_checkpoint():
    """stop_match depth: the feel noted as a checkpoint was passed is compared with the running median of unstopped
    presses at that checkpoint, not with their peaks; the deepest checkpoint passed is the one judged."""
    from studyctl.participants.palpator_press import _Segment

    person = VirtualPalpator({"stop_ratio": 1.6, "stop_match": "depth"})
    grid = {"columns": 7, "rows": 1, "cell_mm": 20.0}
    person.begin_trial(TrialInfo("linear", 600.0, 50.0, public={"grid": grid}), np.random.default_rng(0))
    for i, shallow in enumerate((1.0, 1.1, 9.0, 1.2, 1.3, 1.4)):
        person._notes = {("balloon_psi", "0.4"): shallow, ("balloon_psi", "1"): 10.0 * shallow,
                         ("balloon_psi", "peak"): 10.0 * shallow, ("vibration_ms2", "peak"): 0.0}
        person._end_segment(_Segment("press", 1.0, (0.0, 0.0, 0.0), (0.0, 0.0, 3.0), cell=(i + 1, 1), intended=3.0,
                                     stopped=shallow == 9.0))  # a stopped press is not plain pressing
    assert person._usual_at[("balloon_psi", "0.4")] == pytest.approx(1.2)
    assert person._usual_at[("balloon_psi", "1")] == pytest.approx(12.0)
    person._notes = {("balloon_psi", "0.4"): 1.6 * 1.2 + 0.01}  # part-way down, well above plain tissue there
    assert person._strong({"balloon_psi": 2.0})  # (the peak rule would need 1.6 x 12 psi)
    person._notes = {("balloon_psi", "0.4"): 1.6 * 1.2 - 0.01}
    assert not person._strong({"balloon_psi": 50.0 / 3.0})  # the current feel is not what is compared
    person._notes = {("balloon_psi", "0.4"): 5.0, ("balloon_psi", "1"): 12.0}
    assert not person._strong({})  # the deepest checkpoint passed decides: plain at the bottom
    peak = VirtualPalpator({"stop_ratio": 1.6})
    peak.begin_trial(TrialInfo("linear", 600.0, 50.0, public={"grid": grid}), np.random.default_rng(0))
    peak._notes = {("balloon_psi", "0.4"): 5.0}
    assert not peak._strong({"balloon_psi": 2.0}) and peak._usual_at == {}


def _practised_stops(stop_ratio: float) -> tuple[VirtualPalpator, int]:
    """A person who practised first (learning cue weights), then one bio-inspired trial pressing slowly (4 mm/s) to
    v5's depth: the person and how many of the trial's presses a strong cue ended."""
    from studyctl.controllers.bio_inspired import BioInspiredController
    from studyctl.participants.palpator_perception import STOP

    person = VirtualPalpator({"familiarise": True, "report_rule": "odds", "stop_ratio": stop_ratio,
                              "press_speed_mm_s": 4.0, "depth_mm": 5.3})
    trial_after_practice(person, BioInspiredController, 0)
    return person, sum(ev.felt.get(STOP, 0) for ev in person.evidence.values())


@pytest.mark.slow  # two trials after practice, ~4 s
def test_stop_ratio_acts_for_a_person_who_practised():
    """The running median of plain pressing is kept whatever practice learnt (ce40401 chained it to the
    no-practice branch, so v5's stop_ratio never acted), and a press then stops on a cue far above it: at 4 mm/s the
    vibration over a tumour passes 1.6 times the median on the way down (at v5's 18.9 mm/s it never does:
    scripts/palpation_stop_ratio.py)."""
    person, stops = _practised_stops(1.6)
    assert person.cues is not None  # practice learnt weights: the branch the old code left the median out of
    assert set(person._usual) == {"balloon_psi", "vibration_ms2"} and min(person._usual.values()) > 0
    assert stops > 0
    off, none = _practised_stops(0.0)
    assert none == 0 and off._usual == {}


def test_the_settle_trace_is_kept_and_read_in_one_channel_order():
    """lift_rule settled: the press's trace (palpator.py) and the rise test on it (palpator_press.py) index the
    same CHANNELS: a vibration rise of more than its Weber step (0.2) over settle_s is a rise, the same step on the
    balloon's slot (Weber 0.1) read as vibration would not be; a cue the trace does not keep (the view) is none."""
    from studyctl.participants.palpator_press import CHANNELS, _Segment

    assert CHANNELS == ("balloon_psi", "vibration_ms2")
    person = VirtualPalpator({"lift_rule": "settled"})
    grid = {"columns": 7, "rows": 1, "cell_mm": 20.0}
    person.begin_trial(TrialInfo("linear", 600.0, 50.0, public={"grid": grid}), np.random.default_rng(0))
    seg = _Segment("press", 10.0, (0.0, 0.0, 0.0), (0.0, 0.0, 3.0), cell=(1, 1), ramp=1.0, intended=3.0)
    feel = [{"balloon_psi": 1.0, "vibration_ms2": 2.0, "view": {"depth_mm": d}} for d in (1.0, 2.0, 3.0)]
    for f in feel:
        person._hold_while_rising(seg, 0.5, f)  # descending: traced, never held
    assert seg.trace == [(1.0, 2.0)] * 3 and not person._rising(seg)
    person._hold_while_rising(seg, 0.5, {"balloon_psi": 1.0, "vibration_ms2": 2.0 * 1.15})
    assert not person._rising(seg)  # 15 %: above the balloon's Weber step, below the vibration's
    person._hold_while_rising(seg, 0.5, {"balloon_psi": 1.0, "vibration_ms2": 2.0 * 1.25})
    assert seg.trace[-1] == (1.0, 2.5) and person._rising(seg)
