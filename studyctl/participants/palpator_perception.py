"""What the seed-000 virtual palpator takes from a press (:mod:`studyctl.participants.palpator`): while pressing it
notes what the balloon and the motor deliver at each checkpoint of the believed depth and at their strongest, and the
camera's tip depth at the bottom; when the press ends each note is felt once through the person's Weber sense
(:class:`studyctl.models.perception.Sense`) and added, as a log-percept, to the cell's evidence. In practice each
press's log-percepts are also kept for learning the cue weights; after practice they are combined by them; with
``stop_ratio`` the unstopped presses' strongest feel keeps a running median (what pressing plain sponge feels like).

:class:`PressNotes` is a mixin of :class:`~studyctl.participants.palpator.VirtualPalpator`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from studyctl.participants.palpator_press import CHANNELS, _Segment

VISUAL = ("view", "yield")  # the note key of the camera cue: hand depth / seen tip depth at the bottom
STOP = ("stop", "early")  # the note key of a press stopped by a strong sensation
TRAVEL = ("travel", "stop")  # the note key of how far the hand went before the feedback said enough (log 1/depth)
_NUMBER = (int, float)  # a delivered value that is a number (what isinstance(v, int | float) accepts)


@dataclass
class _CellEvidence:
    """What the presses on one cell left: log-percepts per note, how often each note was felt, the presses."""

    logs: dict[tuple[str, str], list[float]] = field(default_factory=dict)  # (channel, checkpoint) -> log percepts
    felt: dict[tuple[str, str], int] = field(default_factory=dict)
    presses: int = 0
    combined: list[float] = field(default_factory=list)  # each press's evidence by the cue weights learnt in practice
    first: dict[tuple[str, str], float] | None = None  # the first press's log-percepts (to judge a learnt rule by)


class PressNotes:
    """Mixin of :class:`~studyctl.participants.palpator.VirtualPalpator`: notes a press, then turns it into evidence."""

    def _note(self, percept: Mapping[str, Any]) -> None:
        """Note what the actuators deliver (this tick's percept is the feel at the previous tick's depth)."""
        seg = self._pressing
        if seg is None:
            return
        believed = self._belief_depth
        notes = self._notes
        for ch, peak_key, cp_keys in self._note_keys:
            v = percept.get(ch)
            # (int, float), not int | float: the same test, but a tuple is checked faster (this runs every tick)
            v = float(v) if isinstance(v, _NUMBER) and math.isfinite(v) else 0.0
            if v > notes.get(peak_key, 0.0) or peak_key not in notes:
                notes[peak_key] = v
            if cp_keys[-1][1] in notes:
                # checkpoints increase, so the deepest one noted means all are (the usual case once a press is down)
                continue
            for c, ck in cp_keys:
                if ck not in notes and believed >= c * seg.intended - 1e-9:
                    notes[ck] = v
        view = percept.get("view")
        # a dict is a Mapping: the exact type check first spares the ABC's slower isinstance on every tick
        if (type(view) is dict or isinstance(view, Mapping)) and believed > 0:
            seen = view.get("depth_mm")
            # at the deepest point of the press: the hand's depth against the tip depth the camera shows
            if isinstance(seen, _NUMBER) and seen > 0 and believed >= notes.get(("view", "hand"), 0.0):
                notes[("view", "hand")] = believed
                notes[("view", "seen")] = float(seen) / seg.scale  # seen as a fraction of what the hand did

    def _end_segment(self, seg: _Segment) -> None:
        if seg.kind != "press":
            self._notes = {}
            return
        ev = self.evidence.setdefault(seg.cell, _CellEvidence())
        ev.presses += 1
        rng = self._rng
        notes = self._notes
        hand, seen = notes.pop(("view", "hand"), 0.0), notes.pop(("view", "seen"), 0.0)
        press: dict[tuple[str, str], float] = {}  # this press's log-percepts, note by note
        for key, value in notes.items():
            observed = self.senses[key[0]].observe(value, rng)
            if observed > 0:
                ev.felt[key] = ev.felt.get(key, 0) + 1
                press[key] = math.log(observed)
                ev.logs.setdefault(key, []).append(press[key])
        if hand > 0 and seen > 0 and self.params["visual_trust"] > 0:
            # the instrument yields more on stiffer tissue: hand depth / seen depth grows over a tumour
            observed = self.senses["view"].observe(seen, rng)
            press[VISUAL] = math.log(hand / observed)
            ev.logs.setdefault(VISUAL, []).append(press[VISUAL])
            ev.felt[VISUAL] = ev.felt.get(VISUAL, 0) + 1
        if seg.stopped:
            ev.felt[STOP] = ev.felt.get(STOP, 0) + 1
            # how far the hand had gone when the feedback said enough: less travel over stiffer tissue
            travel = self.senses["travel"].observe(max(seg.end[2] / seg.scale, 1e-3), rng)
            if travel > 0:
                press[TRAVEL] = -math.log(travel)
                ev.logs.setdefault(TRAVEL, []).append(press[TRAVEL])
                ev.felt[TRAVEL] = ev.felt.get(TRAVEL, 0) + 1
        if ev.first is None:
            ev.first = press
        if self._practice:
            self._press_logs.append((seg.cell, press))
        elif self.cues is not None:
            combined = self.cues.combine(press)
            if combined is not None:
                ev.combined.append(combined)
        # Kept for every person whose stop_ratio is set, practised or not (ce40401 chained it to the practice
        # branches above, so from then on only an unpractised person kept it, and counted stopped presses too).
        if self._stop_ratio and not seg.stopped:
            for ch in CHANNELS:  # only unstopped presses show what pressing all the way usually feels like
                _keep_median(self._peaks, self._usual, ch, notes.get((ch, "peak"), 0.0))
            if self._stop_by_depth:
                self._keep_plain_at_depth(notes)
        self._notes = {}
        self._pressing = None

    def _keep_plain_at_depth(self, notes: Mapping[tuple[str, str], float]) -> None:
        """``stop_match: depth``: add an unstopped press's feel at each checkpoint it passed to that checkpoint's
        running median (what pressing plain tissue feels like that far down; from 5 presses on)."""
        for _ch, _peak, cp_keys in self._note_keys:
            for _c, ck in cp_keys:
                if ck in notes:
                    _keep_median(self._plain_at, self._usual_at, ck, notes[ck])


def _keep_median(history: dict, usual: dict, key: object, value: float) -> None:
    """Add ``value`` to ``key``'s history and, from 5 values on, keep their median as ``usual[key]`` (what pressing
    plain tissue usually feels like, as a stop rule compares it)."""
    seen = history.setdefault(key, [])
    seen.append(value)
    if len(seen) >= 5:
        usual[key] = float(np.median(seen))
