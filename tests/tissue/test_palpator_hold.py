"""What the tissue palpator's hand gets during a held press and how it judges it: steadiness is a criterion
over time (the same at any loop rate, and reached under seed 003's on/off push), and presses held at
different depths are compared at like depths (a deeper press of uniform tissue is not a nodule)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.participants.tissue_perception import _depth_matched
from studyctl.plugins.interfaces import TrialInfo


def _person(rate_hz: float) -> VirtualTissuePalpator:
    p = VirtualTissuePalpator({})
    p.begin_trial(TrialInfo(condition="FF", time_limit_s=10.0, rate_hz=rate_hz, visual="realtime", public={}),
                  np.random.default_rng(0))
    return p


def _steady_after(rate_hz: float, push) -> float:
    """Feed a held press's force tick by tick; the first time (s) the push is judged steady."""
    p = _person(rate_hz)
    press = {"w_t": [], "w_c": [], "w_felt": 0.0, "w_since": None}
    dt = 1.0 / rate_hz
    for k in range(1, int(3.0 * rate_hz)):
        p._phase_t = k * dt
        if p._steady(press, push(k * dt)):
            return k * dt
    return math.inf


def _chatter(t: float) -> float:
    """seed 003's FF under a held stylus: the push rising to a 1.5 N overshoot, 0.1 s of no normal force while
    the hand rebounds, then the table force switched on and off at ~30 Hz (none while the depth decreases)."""
    if t < 0.03:
        return 1.5 * t / 0.03
    if t < 0.13:
        return 0.05
    return 0.57 if (t * 30.0) % 1.0 < 0.5 else 0.03


def test_an_on_off_push_is_judged_steady_after_the_same_time_at_any_loop_rate():
    t250, t1000 = _steady_after(250.0, _chatter), _steady_after(1000.0, _chatter)
    assert 0.13 < t250 < 0.6  # after the overshoot and the rebound (0.13 s), not at the timeout
    assert t1000 == pytest.approx(t250, abs=0.02)


def test_a_rising_push_is_not_steady_and_no_push_needs_no_wait():
    assert _steady_after(250.0, lambda t: 0.5 + 5.0 * t) == math.inf  # 5 N/s, faster than steady_rate_n_s
    assert _steady_after(250.0, lambda t: 0.0) == pytest.approx(1 / 250.0)
    assert _steady_after(250.0, lambda t: 0.8) <= 4 / 250.0  # a push that stays put: at once
    assert _steady_after(1000.0, lambda t: 0.8 + 1.0 * t) <= 4 / 1000.0  # 1 N/s: a slow drift


def test_presses_are_compared_with_the_tissue_at_the_same_depth():
    rng = np.random.default_rng(1)
    depths = list(1.6 + 0.5 * rng.random(40)) + [4.7]  # the first press of a trial held much deeper
    pushes = [0.2 * d**1.7 for d in depths]  # uniform, Hertz-like tissue
    depths.append(1.8)
    pushes.append(1.3 * 0.2 * 1.8**1.7)  # a nodule: 30 % more push at its depth
    survey = np.ones(len(depths), dtype=bool)
    cue = _depth_matched(np.array(pushes), np.array(depths), survey)
    contrast = cue / np.median(cue) - 1.0
    assert abs(contrast[-2]) < 0.05  # force per depth alone reads it ~60 % stiffer
    assert (0.2 * 4.7**1.7 / 4.7) / (0.2 * 1.8**1.7 / 1.8) > 1.6
    assert contrast[-1] == pytest.approx(0.3, abs=0.03)
    assert np.max(np.abs(contrast[:-2])) < 0.02


def _press_through(person: VirtualTissuePalpator, seen_per_told: float, told_mm: float = 4.0) -> None:
    """One press whose watched point went ``seen_per_told`` mm into the tissue per mm the hand was told to go."""
    person._hand = [0.0, 0.0, 20.0 - told_mm]
    press = {"h": 25.0, "in_at": (25.0, 20.0)}
    person._adapt_press_gain(press, (0.0, 0.0, 25.0 - seen_per_told * told_mm))


def test_the_pressing_gain_adapts_to_how_little_the_watched_point_yields():
    adapting = VirtualTissuePalpator({"press_adaptation": 0.3, "max_press_boost": 4.0})
    fixed = VirtualTissuePalpator({})  # press_adaptation 0: the press slows with the yield, as before
    for person in (adapting, fixed):
        person.begin_trial(TrialInfo(condition="PHF_FF", time_limit_s=10.0, rate_hz=250.0, visual="realtime",
                                     public={}), np.random.default_rng(0))
    yields = []
    for _ in range(12):
        for person in (adapting, fixed):
            _press_through(person, 0.3)
        yields.append(adapting._press_yield)
    assert yields[0] == pytest.approx(1.0 - 0.3 * 0.7)  # one press moves it 30 % of the way
    assert yields[-1] == pytest.approx(0.3, abs=0.02)  # within a dozen presses, about the yield seen
    assert fixed._press_yield == 1.0
    for _ in range(30):
        _press_through(adapting, 0.05)  # a point that hardly moves: the boost is capped
    assert adapting._press_yield == pytest.approx(0.25, abs=1e-3)
    before = adapting._press_yield
    adapting._hand = [0.0, 0.0, 19.8]
    adapting._adapt_press_gain({"h": 25.0, "in_at": (25.0, 20.0)}, (0.0, 0.0, 25.0))  # 0.2 mm told: nothing learnt
    assert adapting._press_yield == before
    adapting.begin_trial(TrialInfo(condition="FF", time_limit_s=10.0, rate_hz=250.0, visual="realtime", public={}),
                         np.random.default_rng(1))
    assert adapting._press_yield == 1.0  # a new condition is learnt afresh
