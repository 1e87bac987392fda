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

    def height(x: float, y: float) -> float:
        asked.append((x, y))
        return 0.0  # a flat surface at z = 0: everything above 0.5 mm is in the air

    p._height = height
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
