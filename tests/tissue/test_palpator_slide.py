"""The tissue palpator's sliding survey (slide_survey): it starts only where a press saw the cursor lag the hand,
turns the rest of the survey into one slide per line, and reads the cursor's sideways slowing per window."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from studyctl.participants.tissue_cue_learning import excess, sums
from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.plugins.interfaces import TrialInfo

EXACT = {"visual_weber": 0.0, "depth_weber": 0.0, "force_weber": 0.0}


def _person(**params) -> VirtualTissuePalpator:
    p = VirtualTissuePalpator(params)
    p.begin_trial(TrialInfo(condition="PHF", time_limit_s=10.0, rate_hz=250.0, visual="realtime", public={}),
                  np.random.default_rng(0))
    p._dt = 0.004
    p._stage = "survey"
    return p


def _probe(person: VirtualTissuePalpator, hand_per_cursor: float) -> dict:
    """The first survey press at (10, 10) has been recorded; the plan holds the rest of two lines."""
    person._plan = [(10.0, 20.0), (20.0, 20.0), (30.0, 20.0), (30.0, 10.0), (20.0, 10.0)]  # popped from the end
    person._presses = [{"x": 10.0, "y": 10.0, "force": math.nan, "ratio": 1.6, "stage": "survey"}]
    return {"x": 10.0, "y": 10.0, "h": 25.0, "track": [(0.0, 0.0), (2.0, 2.0 * hand_per_cursor)]}


def test_the_survey_turns_into_one_slide_per_line_only_where_the_cursor_lags():
    sliding = _person(slide_survey=True)
    sliding._slide_switch(_probe(sliding, 1.8))
    assert sliding._slide_mode
    assert sliding._plan == [(30.0, 20.0), (10.0, 10.0)]  # line starts, the probe's line first (popped from the end)
    assert sliding._slide_ends == {(10.0, 10.0): (30.0, 10.0), (30.0, 20.0): (10.0, 20.0)}
    assert sliding._presses == []  # the probe press is not one of the slide's records
    for person, lag in ((_person(slide_survey=True), 1.0), (_person(), 1.8)):  # no lag seen; a presser
        before = list(person._plan if person._plan else [])
        person._slide_switch(_probe(person, lag))
        assert not person._slide_mode
        assert len(person._presses) == 1 and person._plan != before


def test_a_slide_records_the_sideways_slowing_per_window_of_cursor_travel():
    person = _person(slide_survey=True, slide_window_mm=4.0, **EXACT)
    person._slide_mode = True
    person._slide_ends = {(10.0, 10.0): (40.0, 10.0)}
    person._target = (10.0, 10.0, 20.0)
    press = {"x": 10.0, "y": 10.0, "h": 25.0}
    assert person._slide_start(press, (10.0, 10.0, 20.0))
    assert person._phase == "slide" and person._target == (40.0, 10.0, 20.0)
    hand, cursor = 10.0, 10.0
    done = False
    for k in range(400):
        slowed = 18.0 <= cursor < 22.0  # the cursor moves half as far as the hand here (stiffer ahead)
        hand += 0.2
        cursor += 0.1 if slowed else 0.2
        person._phase_t = (k + 1) * 0.004
        done = person._slide_tick(press, (cursor, 10.0, 20.0), (cursor, 10.0, 20.0), (hand, 10.0, 20.0), 0.0)
        if done:
            break
    assert done
    rows = person._presses
    assert [r["stage"] for r in rows] == ["survey"] * len(rows)
    assert len(rows) == 7  # 27 mm of cursor travel, a record per 4 mm (a window closes on the tick past it)
    slowest = max(rows, key=lambda r: r["ratio"])
    assert slowest["x"] == pytest.approx(20.0, abs=1.0)  # at the window's middle, where the cursor slowed
    assert slowest["ratio"] > 1.8  # the hand went nearly twice as far as the cursor there
    assert all(r["ratio"] == pytest.approx(1.0) for r in rows if abs(r["x"] - 20.0) > 4.0)
    assert all(r["ratio_seen"] == pytest.approx(5.0) for r in rows)  # the cursor 5 mm into the tissue
    assert all(math.isnan(r["force"]) for r in rows)  # nothing pushed back (no force feedback)


def test_a_slide_that_shows_no_sideways_slowing_goes_back_to_pressing():
    """By equation 3 (lateral_ratio: horizontal) a slid cursor nearly keeps pace with the hand (a lag of 0.05, under
    a quarter of the probe press's): after that first line the person presses the remaining points, the slid line's
    included, and keeps none of the slide's records."""
    for q, slides in ((1.05, False), (1.4, True)):  # against a probe press that lagged by 0.8
        person = _person(slide_survey=True)
        person._slide_switch(_probe(person, 1.8))
        person._plan.pop()  # the first line's start is taken and slid
        person._presses = [{"x": 10.0 + k, "y": 10.0, "ratio": q, "stage": "survey"} for k in range(5)]
        person._slide_check(0)
        assert person._slide_mode is slides
        if slides:
            assert len(person._presses) == 5 and person._plan == [(30.0, 20.0)]
        else:
            assert person._presses == []
            assert person._plan[::-1] == [(20.0, 10.0), (30.0, 10.0), (30.0, 20.0), (20.0, 20.0), (10.0, 20.0)]
            person._slide_switch(_probe(person, 1.8))  # it does not try sliding again
            assert not person._slide_mode


def _survey(person: VirtualTissuePalpator) -> None:
    """A 7 x 7 survey of uniform tissue with one nodule press in the middle: the push 1.5 % stiffer there (its
    noise 1 %: a small nodule pressed from the side), the sideways slowing of a slide 60 % stronger (noise 25 %)."""
    rng = np.random.default_rng(3)
    rows = []
    for i in range(7):
        for j in range(7):
            nodule = i == 3 and j == 3
            e1, e2 = (0.0, 0.0) if nodule else rng.normal(size=2)  # the nodule press reads its mean contrasts
            felt = 1.0 * (1.015 if nodule else 1.0) * (1.0 + 0.01 * e1)
            lag = 0.4 * (1.6 if nodule else 1.0) * (1.0 + 0.25 * e2)
            depth = 4.5 + rng.random()  # the depths scatter; neither cue depends on them here
            rows.append({"x": 8.0 * i, "y": 8.0 * j, "force": felt / depth, "felt": felt, "seen": depth,
                         "ratio": 1.0 + lag, "ratio_seen": depth, "stage": "survey"})
    person._presses = rows
    person._air_dc.extend([1.0] * 10)
    person._air_dh.extend([1.0] * 10)


def test_a_slid_survey_adds_each_cue_as_evidence_not_as_one_contrast():
    """Averaged as estimates of one contrast, the push (small contrast, tiny noise) drowns the slide's clear
    slowing: the nodule press stands out by little more than the push's own 1.5 SDs; counted as evidence in each
    cue's own SDs (Stouffer) it stands out by more than either cue alone."""
    zs = {}
    for mode in (False, True):
        person = _person(slide_survey=True, baseline_radius_mm=100.0)
        person._slide_mode = mode
        _survey(person)
        pts, contrast, sigma = person._evidence()
        middle = int(np.argmin(np.hypot(pts[:, 0] - 24.0, pts[:, 1] - 24.0)))
        zs[mode] = contrast[middle] / sigma[middle]
        assert person.perceived["cues"] == ["force", "cursor"]
    assert zs[False] < 2.2
    assert zs[True] > 1.5 * zs[False]


def test_a_steadier_hold_while_sliding_against_a_push_only_when_asked():
    """slide_damping: the device's grip_damping goes up while a slide meets a push, back to 1 after it; with the
    default nothing is ever sent (the device keeps its relaxed hold), nor without a push (no force feedback)."""
    off, pushless, steady = _person(), _person(slide_damping=3.0), _person(slide_damping=3.0)
    for person in (off, pushless, steady):
        person._phase = "slide"
    assert off._grip(0.8) is None and pushless._grip(0.0) is None
    assert steady._grip(0.8) == 3.0
    assert steady._grip(0.0) is None  # still sliding: the steadier hold is kept when the push drops for a tick
    steady._phase = "lift"
    assert steady._grip(0.0) == 1.0 and steady._grip(0.0) is None


def test_the_device_hand_holds_the_handle_steadier_with_more_grip_damping():
    """A step of the hand's wanted position: the relaxed hold (damping ratio 0.33) overshoots; grip_damping 3
    (ratio 1.0) does not. Default inputs keep the relaxed hold."""
    from studyctl.devices.force3d import SimulatedForceDevice

    peaks = {}
    for grip in (None, 3.0):
        device = SimulatedForceDevice({}, None, np.random.default_rng(0))
        device.open()
        device.apply_input({"x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0})
        device.read(0.0)
        step = {"x_mm": 0.0, "y_mm": 0.0, "z_mm": 5.0}
        if grip is not None:
            step["grip_damping"] = grip
        device.apply_input(step)
        zs = [device.read(0.004 * k).values["z_mm"] for k in range(1, 250)]
        peaks[grip] = max(zs)
        assert zs[-1] == pytest.approx(5.0, abs=0.05)
    assert peaks[None] > 5.0 * 1.25  # ~33 % overshoot at ratio 0.33
    assert peaks[3.0] < 5.0 * 1.01


def _slid(person: VirtualTissuePalpator, push_shift: float, seed: int = 5, slow_shift: float = 2.4) -> None:
    """A slid 15 x 15 survey (noise 1 % on the push, 25 % on the slowing) with a 3 x 3 patch over a nodule in the
    middle where the slowing is ``slow_shift`` noise SDs stronger and the push ``push_shift`` noise SDs stronger."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(15):
        for j in range(15):
            nodule = abs(i - 7) <= 1 and abs(j - 7) <= 1
            e1, e2 = rng.normal(size=2)
            felt = 1.0 + 0.01 * ((push_shift if nodule else 0.0) + e1)
            lag = 0.4 * (1.0 + 0.25 * ((slow_shift if nodule else 0.0) + e2))
            depth = 4.5 + rng.random()
            rows.append({"x": 4.0 * i, "y": 4.0 * j, "force": felt / depth, "felt": felt, "seen": depth,
                         "ratio": 1.0 + lag, "ratio_seen": depth, "stage": "survey"})
    person._presses = rows
    person._air_dc.extend([1.0] * 10)
    person._air_dh.extend([1.0] * 10)


def _nodule_z(fusion: str, push_shift: float, person: VirtualTissuePalpator | None = None) -> float:
    person = person or _person(slide_survey=True, baseline_radius_mm=200.0, slide_fusion=fusion)
    person._slide_mode = True
    _slid(person, push_shift)
    pts, contrast, sigma = person._evidence()
    spot = np.hypot(pts[:, 0] - 28.0, pts[:, 1] - 28.0) <= 4.5
    w = 1.0 / sigma[spot] ** 2
    return float((w * contrast[spot]).sum() / np.sqrt(w.sum()))  # the patch's evidence in noise SDs


def test_a_slid_survey_weighs_each_cue_by_what_it_has_shown():
    """slide_fusion: reliability. Where the push shows nothing of a nodule the slowing shows clearly, equal weights
    (Stouffer) cost the slowing's evidence about 1/√2; weighted by what each cue showed over the survey, the patch
    stands out nearly as much as by the slowing alone. Where both show it alike, both weightings agree."""
    blind_equal, blind_weighted = _nodule_z("stouffer", 0.0), _nodule_z("reliability", 0.0)
    assert blind_weighted > 1.25 * blind_equal
    both_equal, both_weighted = _nodule_z("stouffer", 2.4), _nodule_z("reliability", 2.4)
    assert abs(both_weighted / both_equal - 1.0) < 0.1
    assert both_weighted > blind_weighted  # the push adds where it shows the nodule


def _slid_trials(person: VirtualTissuePalpator, seeds, slow_shift: float) -> None:
    """The person slides one survey per seed (the push blind to the nodule) and ends each trial."""
    person._slide_mode = True
    for seed in seeds:
        _slid(person, 0.0, seed=seed, slow_shift=slow_shift)
        person._evidence()
        person._cue_learning.commit()


def test_pooled_cue_weights_are_learnt_over_the_persons_own_slid_trials():
    """slide_fusion: pooled. With no slid trial behind it the person weighs its two cues more alike than one
    trial's estimate does (its prior: equally reliable); after slid trials in which the slowing showed its nodule
    clearly and the push nothing, it weighs the slowing far above the push, so a faint nodule stands out more
    than by equal weights or by one trial's estimate; what it learnt is its memory, so a resumed session goes on
    with it, and nobody else stores anything."""
    def ratio(person: VirtualTissuePalpator) -> float:
        return person._slide_weights["force"] / person._slide_weights["cursor"]

    equal, per_trial = _nodule_z("stouffer", 0.0), _nodule_z("reliability", 0.0)
    single = _person(slide_survey=True, baseline_radius_mm=200.0, slide_fusion="reliability")
    novice = _person(slide_survey=True, baseline_radius_mm=200.0, slide_fusion="pooled")
    _nodule_z("reliability", 0.0, single)
    assert equal < _nodule_z("pooled", 0.0, novice) < per_trial
    assert abs(math.log(ratio(novice))) < abs(math.log(ratio(single)))
    person = _person(slide_survey=True, baseline_radius_mm=200.0, slide_fusion="pooled")
    _slid_trials(person, range(20, 26), slow_shift=6.0)
    assert person._cue_learning.past["cursor"][2] == 6 * 225
    practised = _nodule_z("pooled", 0.0, person)
    assert ratio(person) < 0.6 * ratio(single)
    assert practised > per_trial
    resumed = _person(slide_survey=True, baseline_radius_mm=200.0, slide_fusion="pooled")
    resumed.recall(json.loads(json.dumps(person.memory())))
    assert _nodule_z("pooled", 0.0, resumed) == practised
    assert _person(slide_survey=True).memory() == {}


def test_pooled_cue_weights_vary_less_from_trial_to_trial_than_one_trials_estimate():
    """Why pooling: one survey's estimate of each cue's amplitude is noisy (sampling SD ~0.3 at ~200 windows), so
    its weights move from trial to trial with the noise; pooled over the person's earlier trials they move less.
    The ratio of the push's weight to the slowing's over 12 surveys of one kind (the push blind, the slowing 2.4
    SDs stronger at the nodule)."""
    def ratios(fusion: str) -> np.ndarray:
        person = _person(slide_survey=True, baseline_radius_mm=200.0, slide_fusion=fusion)
        person._slide_mode = True
        out = []
        for seed in range(40, 52):
            _slid(person, 0.0, seed=seed)
            person._evidence()
            out.append(person._slide_weights["force"] / person._slide_weights["cursor"])
            if fusion == "pooled":
                person._cue_learning.commit()
        return np.array(out[2:])  # after two trials of experience

    assert np.std(ratios("pooled")) < 0.5 * np.std(ratios("reliability"))


def test_the_stiffer_side_excess_ignores_a_symmetric_wobble_that_the_spread_counts():
    """cue_excess: stiffer. A cue whose records wobble symmetrically more than its robust noise SD says (heavy
    tails: Student t with 3 degrees of freedom) shows a large spread excess with nothing to show; the stiffer side's
    excess stays at noise level, and rises once 5 % of the records are 3 SDs stiffer (a nodule under them)."""
    rng = np.random.default_rng(11)
    wobble = rng.standard_t(3, size=4000)
    nodule = wobble + np.where(np.arange(4000) % 20 == 0, 3.0, 0.0)
    assert excess(*sums(wobble), wobble.size, "spread") > 1.0
    assert abs(excess(*sums(wobble), wobble.size, "stiffer")) < 0.1
    assert excess(*sums(nodule), nodule.size, "stiffer") > 0.3
