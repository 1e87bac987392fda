"""Pseudo-haptic cursor (seed 003 Table 1) and the geometric deformation view (§2.3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from studyctl.errors import ModelParameterError
from studyctl.models.pseudo_haptics import (
    DeformationView,
    PseudoHapticCursor,
    PseudoHapticParams,
    contact_radius,
    deformation_profile,
    deformation_range,
    neighbour_depths,
    ratio,
)


def test_ratios_follow_equations_2_and_3():
    assert ratio(1.0, 0.0) == 1.0
    assert ratio(2.0, 1.0) == pytest.approx(1.0)
    assert ratio(0.8, 3.0) == pytest.approx(0.2)
    assert ratio(1.0, -0.5) == 1.0  # a negative table force counts as none


def test_table_1_normal_and_horizontal_rules():
    c = PseudoHapticCursor(PseudoHapticParams(r0=1.0, resync_mm_per_s=0.0))
    c.reset((0.0, 0.0, 10.0))
    c.step((0.0, 0.0, 10.0), 0.0, 0.0, True, 0.001)  # first tick: nothing to compare with yet
    # indentation increasing (Δf_n > 0): z moves by R_n·D, x/y by R_h·D
    cur = c.step((1.0, 0.0, 9.0), 1.0, 0.25, True, 0.001)
    assert cur == pytest.approx((1.0 / 1.25, 0.0, 10.0 - 1.0 / 2.0))
    assert (c.last_ratio_n, c.last_ratio_h) == pytest.approx((0.5, 0.8))
    # same force as before (Δf_n = 0): the default ratio
    cur2 = c.step((2.0, 0.0, 8.0), 1.0, 0.25, True, 0.001)
    assert np.subtract(cur2, cur) == pytest.approx((1.0, 0.0, -1.0))
    # softer (Δf_n < 0): default ratio as well
    cur3 = c.step((2.0, 1.0, 9.0), 0.4, 0.1, True, 0.001)
    assert np.subtract(cur3, cur2) == pytest.approx((0.0, 1.0, 1.0))


def test_lateral_ratio_table_1_slows_sideways_moves_by_the_normal_force():
    """Table 1 prints R_n for (x, y) moves; equation 3 defines R_h from the (small, rolling) horizontal force.
    By Table 1 a cursor slid sideways onto stiffer tissue slows as a press does; by equation 3 hardly at all."""
    eq3 = PseudoHapticCursor(PseudoHapticParams(r0=1.0, resync_mm_per_s=0.0))
    table1 = PseudoHapticCursor(PseudoHapticParams(r0=1.0, resync_mm_per_s=0.0, lateral_ratio="normal"))
    for c in (eq3, table1):
        c.reset((0.0, 0.0, 10.0))
        c.step((0.0, 0.0, 10.0), 0.87, 0.04, True, 0.004)
    # 1 mm sideways at constant depth onto tissue whose normal force rose (0.87 -> 1.19 N, nodule A at 5 mm)
    assert eq3.step((1.0, 0.0, 10.0), 1.19, 0.06, True, 0.004)[0] == pytest.approx(1.0 / 1.06)
    assert table1.step((1.0, 0.0, 10.0), 1.19, 0.06, True, 0.004)[0] == pytest.approx(1.0 / 2.19)
    assert table1.last_ratio_h == pytest.approx(table1.last_ratio_n)
    # sliding on to softer tissue (Δf_n < 0): the default ratio either way
    assert table1.step((2.0, 0.0, 10.0), 1.0, 0.05, True, 0.004)[0] == pytest.approx(1.0 / 2.19 + 1.0)


def test_increments_not_positions_cursor_never_jumps_when_force_changes():
    c = PseudoHapticCursor(PseudoHapticParams(r0=1.0, resync_mm_per_s=0.0))
    c.reset((5.0, 5.0, 5.0))
    before = c.step((5.0, 5.0, 5.0), 0.0, 0.0, True, 0.001)
    # the force jumps from 0 to 3 N while the hand does not move: the cursor stays where it is
    after = c.step((5.0, 5.0, 5.0), 3.0, 0.5, True, 0.001)
    assert after == before
    # an absolute mapping R·input would have jumped by (1 − 1/4)·5 mm here


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(0.0, 3.3), st.booleans()),
        min_size=2,
        max_size=60,
    ),
    st.floats(0.2, 3.0),
)
def test_cursor_continuity_under_any_force_sequence(moves, r0):
    """Per tick the cursor moves at most R₀·|Δinput| plus the bounded resynchronisation step."""
    resync, dt = 10.0, 0.001
    c = PseudoHapticCursor(PseudoHapticParams(r0=r0, resync_mm_per_s=resync))
    hand = [0.0, 0.0, 0.0]
    c.reset(tuple(hand))
    prev = c.cursor
    for dx, dy, dz, f, contact in moves:
        hand = [hand[0] + dx, hand[1] + dy, hand[2] + dz]
        cur = c.step(tuple(hand), f, 0.2 * f, contact, dt)
        step = math.dist(cur, prev)
        assert step <= r0 * math.sqrt(dx * dx + dy * dy + dz * dz) + resync * dt + 1e-9
        prev = cur


def test_resync_returns_the_cursor_out_of_contact_at_bounded_speed():
    c = PseudoHapticCursor(PseudoHapticParams(r0=1.0, resync_mm_per_s=10.0))
    c.reset((0.0, 0.0, 0.0))
    c.step((0.0, 0.0, 0.0), 0.0, 0.0, True, 0.001)
    for k in range(1, 101):  # press 10 mm at 1 N: the cursor lags by half
        c.step((0.0, 0.0, -0.1 * k), 1.0 + 0.01 * k, 0.0, True, 0.001)
    lag = c.cursor[2] - (-10.0)
    assert lag > 4.0
    positions = [c.step((0.0, 0.0, -10.0), 0.0, 0.0, False, 0.001)[2] for _ in range(2000)]
    steps = np.abs(np.diff(positions))
    assert steps.max() <= 10.0 * 0.001 + 1e-12
    assert positions[-1] == pytest.approx(-10.0)


def test_parameters_are_validated():
    with pytest.raises(ModelParameterError, match="r0"):
        PseudoHapticParams(r0=0.0).validate()
    with pytest.raises(ModelParameterError, match="resync_mm_per_s"):
        PseudoHapticParams(resync_mm_per_s=-1.0).validate()
    with pytest.raises(ModelParameterError, match="lateral_ratio is 'tangential'; allowed: horizontal, normal"):
        PseudoHapticParams(lateral_ratio="tangential").validate()


def test_demarcation_depths_of_figure_3c():
    r = 5.0
    assert contact_radius((2 - math.sqrt(3)) * r / 2, r) == pytest.approx(r / 2)
    assert contact_radius(r, r) == r and contact_radius(2.5 * r, r) == r
    assert [deformation_range(d, r) for d in (0.5, 1.0, 5.0, 9.9, 10.0, 12.0)] == ["a", "b", "c", "c", "d", "d"]


def test_profile_is_continuous_monotone_and_bounded():
    r, taper = 5.0, 20.0
    for depth in (0.3, 2.0, 5.0, 8.0, 12.0):
        rho = np.linspace(0.0, 25.0, 2501)
        u = np.array([deformation_profile(x, depth, r, taper) for x in rho])
        assert u[0] == pytest.approx(depth)  # node A sits at the indenter's lowest point
        assert np.all(u >= 0) and np.all(u <= depth + 1e-12)
        assert np.all(np.diff(u) <= 1e-12)  # falls off with distance
        assert np.max(np.abs(np.diff(u))) < 0.1 * depth + 0.05  # no jumps on a 0.01 mm grid
        assert u[-1] == 0.0
    d = neighbour_depths(4.0, 5.0)
    assert len(d) == 7 and d[0] == 4.0 and all(a >= b for a, b in zip(d, d[1:], strict=False))


def test_view_frames_are_lazy_and_local():
    view = DeformationView(np.arange(0, 121, 2.0), np.arange(0, 121, 2.0), 5.0)
    pending = view.pending(60.0, 40.0, 3.0)
    assert pending._frame is None  # nothing computed until someone draws it
    frame = pending.compute()
    assert pending.compute() is frame
    assert frame.range == "b" and frame.nodes
    assert all(abs(view.xs[i] - 60) <= 20 and abs(view.ys[j] - 40) <= 20 and dz < 0 for i, j, dz in frame.nodes)
    assert min(dz for _, _, dz in frame.nodes) == pytest.approx(-3.0)
    assert view.frame(60.0, 40.0, 0.0).nodes == ()
    assert set(frame.to_dict()) == {"center_mm", "depth_mm", "contact_radius_mm", "range", "nodes"}
