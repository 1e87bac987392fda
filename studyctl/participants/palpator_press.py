"""How the seed-000 virtual palpator moves the probe (:mod:`studyctl.participants.palpator`): the trial as a queue of
segments (a move above a cell, then a press), each press's own noise drawn when it is queued, the taps that fill the
time a stopped press saved, and the rules that end a descent early (a cue strong enough, once the tip has visibly
dented the sponge). The pose at any moment of a segment is a pure function of the segment and the time into it.

:class:`PressPlanning` is a mixin of :class:`~studyctl.participants.palpator.VirtualPalpator`; it uses the trial's
state that ``begin_trial`` sets (``_plan``, ``_rng``, ``_pace``, the grid, the senses, the stop levels).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

# the feedback a press delivers, in this order wherever a press's feel is kept (notes, the settle trace); defined
# here, the module the perception mixin builds on, so both read one tuple without importing each other
CHANNELS = ("balloon_psi", "vibration_ms2")


@dataclass
class _Segment:
    """One step of the plan: a move in the air to above a cell, or a press there (ramp in, hold, ramp out)."""

    kind: str  # "move", "press", "decide"
    duration: float
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    cell: tuple[int, int] | None = None
    ramp: float = 0.0
    intended: float = 0.0  # the depth the participant means to reach
    scale: float = 1.0  # actual / intended depth (motor error)
    stopped: bool = False  # ended early by a strong sensation
    stop_gain: float = 1.0  # this press's felt-strength noise on the stop levels (Weber noise of the magnitude)
    seen_gain: float = 1.0  # this press's visual noise on the minimum dent seen before a stop (stop_min_seen_mm)
    retap: bool = False  # an extra tap after a stopped press (it makes no taps of its own)
    looked: bool = False  # the dwell to judge by eye has been decided
    held: float = 0.0  # time held past the planned hold for a cue still rising (lift_rule: settled)
    lift: str = "planned"  # what the lift waited for: planned, looked (nothing felt), settled (a cue rose)
    trace: list[tuple[float, ...]] = field(default_factory=list)  # felt cues per tick (lift_rule: settled)


class PressPlanning:
    """Mixin of :class:`~studyctl.participants.palpator.VirtualPalpator`: queues probes and taps, stops presses."""

    def _queue_probe(self, cell: tuple[int, int], at: tuple[float, float] | None = None) -> None:
        rng = self._rng
        p = self.params
        if at is None:
            at = (self.origin[0] + (cell[0] - 0.5) * self.cell_mm, self.origin[1] + (cell[1] - 0.5) * self.cell_mm)
        cx = at[0] + p["aim_sd_mm"] * rng.standard_normal()
        cy = at[1] + p["aim_sd_mm"] * rng.standard_normal()
        scale = max(1.0 + p["depth_cv"] * rng.standard_normal(), 0.05)
        depth = p["depth_mm"] * scale
        last = self._plan[-1].end if self._plan else self._pose
        above = (cx, cy, -2.0)
        self._plan.append(_Segment("move", p["move_s"] / self._pace, (last[0], last[1], -2.0), above))
        ramp = depth / (p["press_speed_mm_s"] * self._pace)
        # how strong "enough" feels this time: the stop levels through the person's Weber noise of magnitude
        gain = math.exp(self.senses["balloon_psi"].sigma * rng.standard_normal()) if self._stop_levels else 1.0
        self._plan.append(
            _Segment("press", 2 * ramp + p["hold_s"], above, (cx, cy, depth), cell, ramp, p["depth_mm"], scale,
                     stop_gain=gain, seen_gain=self._seen_gain())
        )

    def _queue_taps(self, seg: _Segment, spare_s: float) -> None:
        """Fill the time a stopped press saved with taps on the same spot, right after it (each to the depth the
        person means to reach, stopped again where the cue says enough)."""
        rng = self._rng
        p = self.params
        taps = min(round(spare_s / max(seg.duration, 1e-3)), p["max_taps"])  # as many as fit, to the nearest one
        above = (seg.end[0], seg.end[1], -2.0)
        for k in range(taps):
            scale = max(1.0 + p["depth_cv"] * rng.standard_normal(), 0.05)
            depth = p["depth_mm"] * scale
            ramp = depth / (p["press_speed_mm_s"] * self._pace)
            gain = math.exp(self.senses["balloon_psi"].sigma * rng.standard_normal())
            self._plan.insert(self._seg_index + 1 + k, _Segment(
                "press", 2 * ramp + p["hold_s"], above, (seg.end[0], seg.end[1], depth), seg.cell, ramp,
                p["depth_mm"], scale, stop_gain=gain, retap=True, seen_gain=self._seen_gain()))

    def _seen_gain(self) -> float:
        """This press's visual noise on the minimum dent. Drawn whenever a stop level is in use, whatever the
        minimum (0 included), so people who differ only in the minimum share their random numbers (a fit compares
        like with like); a person who never stops on a level draws nothing (the default stream is unchanged)."""
        if not self._stop_levels:
            return 1.0
        return math.exp(self.senses["view"].sigma * self._rng.standard_normal())

    def _dented(self, percept: Mapping[str, Any], seg: _Segment) -> bool:
        """Has the tip visibly dented the sponge enough for a haptic cue to end the press? The camera's tip depth
        (the hand's believed depth when there is no view) against the minimum, as seen this press."""
        need = self.params["stop_min_seen_mm"]
        if need <= 0:
            return True
        view = percept.get("view")
        seen = view.get("depth_mm") if isinstance(view, Mapping) else None
        depth = float(seen) if isinstance(seen, int | float) else self._belief_depth
        return depth * seg.seen_gain >= need

    def _strong(self, percept: Mapping[str, Any], gain: float = 1.0) -> bool:
        """A haptic cue strong enough to stop pressing: above an absolute level (as felt this press: ``gain``), or
        well above what normal tissue usually gives (felt as is: large differences, far above the Weber noise)."""
        ratio = self._stop_ratio
        by_peak = ratio and not self._stop_by_depth
        usual = self._usual
        for ch, level in self._stop.items():
            v = percept.get(ch)
            if isinstance(v, int | float) and (v * gain >= level or (by_peak and usual.get(ch, 0.0) > 0
                                                              and v >= ratio * usual[ch])):
                return True
        return bool(ratio and self._stop_by_depth and self._above_plain_at_depth(ratio))

    def _above_plain_at_depth(self, ratio: float) -> bool:
        """``stop_match: depth``: did this press feel a cue ``ratio`` times what plain tissue gave at the deepest
        checkpoint the press has passed? (The note at a checkpoint is the feel as it was passed, so the comparison
        is at the same fraction of the intended depth, not against a cue that has since grown.)"""
        notes, usual = self._notes, self._usual_at
        for _ch, _peak, cp_keys in self._note_keys:
            for _c, ck in reversed(cp_keys):
                if ck in notes:
                    u = usual.get(ck, 0.0)
                    if u > 0 and notes[ck] >= ratio * u:
                        return True
                    break
        return False


    def _rising(self, seg: _Segment) -> bool:
        """Did a felt cue rise by more than the person's Weber fraction over the last ``settle_s`` of this press?
        (``seg.trace`` holds the delivered values of the press's ticks, newest last.)"""
        trace = seg.trace
        if len(trace) < 2:
            return False
        back = trace[max(len(trace) - 1 - self._settle_ticks, 0)]
        now = trace[-1]
        for i, ch in enumerate(CHANNELS):
            sense = self.senses[ch]
            if now[i] > sense.threshold and now[i] > back[i] * (1.0 + sense.weber):
                return True
        return False


def _lerp(a, b, f):
    """The point a fraction ``f`` of the way from pose ``a`` to pose ``b`` (3-tuples; written out: a move's every tick
    calls it)."""
    return (a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f)


def _stop_press(seg: _Segment, elapsed: float, keep_tempo: bool = False) -> None:
    """End the descent now: the press holds at the depth reached, then releases at the same speed (with
    ``keep_tempo`` it holds for the rest of the press's planned time: the press keeps the person's rhythm)."""
    reached = seg.end[2] * elapsed / seg.ramp if seg.ramp > 0 else seg.end[2]
    hold = seg.duration - 2 * seg.ramp
    if keep_tempo:
        hold = seg.duration - 2 * elapsed
    seg.end = (seg.end[0], seg.end[1], reached)
    seg.ramp = elapsed
    seg.duration = 2 * elapsed + hold
    seg.stopped = True


def _press_pose(seg: _Segment, elapsed: float) -> tuple[float, float, float]:
    """Depth profile of a press: ramp in, hold, ramp out (trapezoid), at the segment's cell position."""
    depth = seg.end[2]
    ramp = seg.ramp
    hold = seg.duration - 2 * ramp
    if elapsed < ramp:
        d = depth * elapsed / ramp if ramp > 0 else depth
    elif elapsed < ramp + hold:
        d = depth
    else:
        d = depth * max(0.0, 1.0 - (elapsed - ramp - hold) / ramp) if ramp > 0 else 0.0
    return (seg.end[0], seg.end[1], d)
