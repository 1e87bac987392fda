"""The virtual palpator's cursor cue reads hand over cursor travel while the cursor descends, so a hand that
wobbles back up mid-press (up at R₀, down again at the reduced ratio) does not bias it."""

from __future__ import annotations

import numpy as np
import pytest

from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.plugins.interfaces import TrialInfo


def _press(moves: list[tuple[float, float]]) -> float:
    """Feed one press tick by tick (cursor and hand z increments) and return the recorded ratio."""
    p = VirtualTissuePalpator({"visual_weber": 0.0, "ratio_window_mm": 2.0})
    p.begin_trial(TrialInfo(condition="PHF", time_limit_s=10.0, rate_hz=250.0, visual="realtime", public={}),
                  np.random.default_rng(0))
    h = 10.0
    p._phase, p._phase_t, p._replan, p._stage = "press", 0.0, False, "survey"
    p._target = (0.0, 0.0, h - 50.0)  # never reached: the press stays in its pressing phase
    p._press = {"x": 0.0, "y": 0.0, "h": h, "track": [], "last": None, "f_sum": 0.0}
    cz = hz = h + 0.1  # just above the surface
    for dc, dh in moves:
        cz, hz = cz + dc, hz + dh
        # steered by the cursor (press_steer: seen, the default), so ctrl is also the steering point
        p._advance((0.0, 0.0, cz), (0.0, 0.0, cz), (0.0, 0.0, hz), 0.0, (0.0, 0.0, cz))
    press = p._press
    press["bx"], press["by"], press["bz"] = 0.0, 0.0, cz
    p._record(press)
    return p._presses[-1]["ratio"]


def test_ratio_is_one_over_r_without_rebound():
    ticks = [(-0.05, -0.05)] * 2 + [(-0.05, -0.1)] * 80  # R = 0.5 in the tissue
    assert _press(ticks) == pytest.approx(2.0)


def test_a_rebound_mid_press_does_not_inflate_the_ratio():
    down = [(-0.05, -0.05)] * 2 + [(-0.05, -0.1)] * 60  # 3 mm into the tissue at R = 0.5
    up = [(0.05, 0.05)] * 8  # the hand springs back 0.4 mm: the cursor follows at R₀ = 1
    again = [(-0.05, -0.1)] * 28  # and presses on at R = 0.5, 1 mm past the earlier bottom
    # Net hand over net cursor travel between new cursor minima would read 2.2 here: the loop's extra hand
    # travel (0.4 mm) is counted as if it had pressed the cursor down.
    assert _press(down + up + again) == pytest.approx(2.0)
