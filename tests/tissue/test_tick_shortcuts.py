"""Per-tick shortcuts of the seed-003 participant and tissue scene (issue 22): they skip work whose result is not
used, and keep every result the long way gives."""

from __future__ import annotations

import numpy as np

from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes import tissue as tissue_scene
from tests.tissue.test_scene_controllers import BASE, _frame_repr, _scene


def _palpator() -> tuple[VirtualTissuePalpator, list[tuple[float, float]]]:
    p = VirtualTissuePalpator({})
    p.begin_trial(TrialInfo(condition="PHF", time_limit_s=10.0, rate_hz=250.0, visual="realtime", public={}),
                  np.random.default_rng(0))
    asked: list[tuple[float, float]] = []

    def in_air(x: float, y: float, z: float) -> bool:
        asked.append((x, y))
        return z > 0.5  # a flat surface at z = 0: everything above 0.5 mm is in the air

    p._height = lambda x, y: 0.0
    p._in_air = in_air
    return p, asked


def test_a_still_hand_does_not_look_up_the_surface_and_keeps_the_same_air_travel():
    p, asked = _palpator()
    # hand still (travel 0 ≤ 1e-3 mm) on ticks 2-3, moving on ticks 4-5; cursor always in the air
    path = [((0.0, 0.0, 10.0), (0.0, 0.0, 10.0)), ((0.0, 0.0, 10.0), (0.0, 0.0, 10.0)),
            ((0.0, 0.0, 10.0), (0.0, 0.0, 10.0)), ((0.0, 0.0, 9.0), (0.0, 0.0, 9.5)),
            ((0.0, 0.0, 8.0), (0.0, 0.0, 9.0))]
    for cursor, handle in path:
        p._observe_air(cursor, handle, cursor)
    assert list(p._air_dc) == [1.0, 1.0] and list(p._air_dh) == [0.5, 0.5]
    assert asked == [(0.0, 0.0), (0.0, 0.0)]  # only the two ticks the hand moved (every tick before)


def test_view_parts_reads_a_controllers_avatar_without_the_merge_helper(monkeypatch):
    s = _scene(needs=BASE | {"view"})
    a, b = {"x_mm": 1.0, "y_mm": 2.0, "z_mm": 3.0}, {"x_mm": 60.0, "y_mm": 61.0, "z_mm": 21.0}
    cases = [
        {"cursor_x_mm": 60.0, "cursor_y_mm": 60.0, "cursor_z_mm": 21.0, "tissue_depth_mm": 3.0,
         "contact_x_mm": 10.0, "contact_y_mm": 12.0},
        {"cursor_x_mm": 60.0, "cursor_y_mm": 60.0, "cursor_z_mm": 30.0, "tissue_depth_mm": 0.0},
        {"cursor_x_mm": None, "cursor_y_mm": 60.0, "cursor_z_mm": 30.0, "tissue_depth_mm": 0.0},
    ]
    expected = [_frame_repr(s.view({**a, **b, **c})) for c in cases]
    picks: list[str] = []
    real_pick = tissue_scene._pick

    def counting_pick(key, *maps):
        picks.append(key)
        return real_pick(key, *maps)

    monkeypatch.setattr(tissue_scene, "_pick", counting_pick)
    assert [_frame_repr(s.view_parts(a, b, c)) for c in cases] == expected
    # the first case's contact point is still picked (deformation); the avatar and depth are read straight
    # in the first two (before: cursor x, y, z and depth picked each time); the third takes the general path
    assert picks[:2] == ["contact_x_mm", "contact_y_mm"] and "cursor_x_mm" not in picks[:2]
    assert picks.count("cursor_x_mm") == 1


def test_in_air_is_the_height_test_it_shortcuts():
    """``in_air`` settles most points from the surface's bounds without the height; it must answer as the height
    test does everywhere: on flat and uneven surfaces, with NaN off the tissue, at the bounds and off the grid."""
    from studyctl.participants.tissue_palpator import _surface_sampler

    rng = np.random.default_rng(6)
    xs, ys = np.arange(0.0, 62.0, 2.0), np.arange(-10.0, 50.0, 2.0)
    flat = np.full((xs.size, ys.size), 25.0)
    uneven = 20.0 + 5.0 * rng.random((xs.size, ys.size))
    for heights in (flat, uneven):
        heights = heights.copy()
        heights[:3], heights[:, -2:] = np.nan, np.nan  # off the tissue
        height, in_air, *_ = _surface_sampler({"xs_mm": xs, "ys_mm": ys, "heights_mm": heights})
        lo, hi = np.nanmin(heights), np.nanmax(heights)
        x = rng.uniform(-5.0, 67.0, 20_000)
        y = rng.uniform(-15.0, 55.0, 20_000)
        x[:4000], y[:2000] = rng.choice(xs, 4000), rng.choice(ys, 2000)  # on grid lines and nodes
        z = np.concatenate([rng.uniform(lo - 2.0, hi + 2.0, 10_000),
                            rng.choice([lo + 0.5, hi + 0.5, lo + 0.5 - 1e-3, hi + 0.5 + 1e-3], 10_000)])
        for a, b, c in zip(x.tolist(), y.tolist(), z.tolist(), strict=True):
            h = height(a, b)
            assert in_air(a, b, c) == (not np.isfinite(h) or c > h + 0.5)
