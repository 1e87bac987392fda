"""``pinpoint_presses`` (tissue palpator, 0 = off): once re-palpation has judged a spot a nodule, the person presses
the side points of its 3 x 3 grid before moving on, to place it (seed 002's task: "pinpoint the found nodule
positions"); the verdict stands, the extra presses do not retest it."""

from __future__ import annotations

from studyctl.participants.tissue_palpator import VirtualTissuePalpator


def _follow_up_presses(pinpoint: int, llrs: list[float]) -> tuple[list[tuple[float, float]], list]:
    person = VirtualTissuePalpator({"pinpoint_presses": pinpoint, "follow_up_spacing_mm": 4.0})
    grid = [(50.0 + ox, 30.0 + oy) for ox in (0.0, -4.0, 4.0) for oy in (0.0, -4.0, 4.0)]
    person._spots = [{"x": 50.0, "y": 30.0, "mu": 1.0, "todo": list(grid), "presses": 0}]
    person._follow_up = {"follow_up_spots": [(50.0, 30.0)], "follow_up_decisions": []}
    it = iter(llrs)
    person._spot_llr = lambda spot: next(it, llrs[-1])
    pressed = []
    while (nxt := person._next_follow_up()):
        pressed += nxt
    return pressed, person._follow_up["follow_up_decisions"]


def test_a_spot_judged_a_nodule_is_pressed_around_before_the_person_moves_on():
    # the test decides "nodule" after the centre press (log-likelihood ratio 0, then 10: past Wald's bound 2.94)
    plain, decided = _follow_up_presses(0, [0.0, 10.0])
    assert plain == [(50.0, 30.0)] and decided == [(50.0, 30.0, "nodule", 1)]
    pinned, decided = _follow_up_presses(4, [0.0, 10.0, -10.0])  # later presses would say "none": not retested
    assert pinned == [(50.0, 30.0), (50.0, 26.0), (50.0, 34.0), (46.0, 30.0), (54.0, 30.0)]
    assert decided == [(50.0, 30.0, "nodule", 1)]


def test_a_spot_dismissed_is_not_pinpointed():
    pressed, decided = _follow_up_presses(4, [0.0, -10.0])
    assert pressed == [(50.0, 30.0), (50.0, 26.0)]  # follow_up_min 2 presses before dismissing, then no pinpointing
    assert decided == [(50.0, 30.0, "none", 2)]
