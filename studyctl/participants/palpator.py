"""A virtual participant who palpates the sponge phantom cell by cell and reports where tumours feel different.

It knows only what a participant knows (the grid, from ``TrialInfo.public``) and what the actuators
deliver (``balloon_psi`` and ``vibration_ms2`` from the device's feedback), felt through a noisy Weber
observer (:class:`studyctl.models.perception.Sense`). It never sees the scene or the tumour sites, so
whether it finds a tumour depends on the controller turning a stiffer spot into a feelable difference.

Behaviour (the paper's instructions: "follow the grid, checking each location one by one", least force,
as quickly as possible):

1. **Sweep**: for every cell in raster order, move above the cell centre (aim noise), press to the target
   depth at a fixed speed (depth noise: the participant believes it pressed to the intended depth),
   hold, release. What the balloon and the motor deliver is noted when the believed depth passes each
   checkpoint (fractions of the target depth) and at its strongest; each note is one observation
   with Weber noise and a detection threshold. Noting the feel at several depths lets a participant use
   whatever depth range a controller conveys best (below saturation, across a piecewise step).
2. **Screen**: for each (channel, checkpoint) the reference is the median over all cells (normal tissue);
   a cell whose mean log-percept exceeds it by ``screen_z`` noise SDs of the mean (or, where normal tissue
   is mostly not felt, that is felt more often than the binomial base rate allows, as a z-score) is
   re-probed ``confirm_presses`` times.
3. **Report**: cells whose mean evidence stays above ``report_z`` (noise SDs of the mean), keeping only
   the strongest of neighbouring cells; then ``finish``. When nothing stood out, it guesses
   ``guesses`` distinct random cells (what a participant without feedback does when told to report).

Parameters marked CHOSEN have no source; the tests show their effect.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from studyctl.errors import ModelParameterError
from studyctl.models.perception import Sense
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo
from studyctl.plugins.params import Param, validate_params

CHANNELS = ("balloon_psi", "vibration_ms2")


@dataclass
class _Segment:
    kind: str  # "move", "press", "decide"
    duration: float
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    cell: tuple[int, int] | None = None
    ramp: float = 0.0
    intended: float = 0.0  # the depth the participant means to reach
    scale: float = 1.0  # actual / intended depth (motor error)


@dataclass
class _CellEvidence:
    logs: dict[tuple[str, str], list[float]] = field(default_factory=dict)  # (channel, checkpoint) -> log percepts
    felt: dict[tuple[str, str], int] = field(default_factory=dict)
    presses: int = 0


class VirtualPalpator(Participant):
    """Virtual participant for the sponge-phantom study: sweeps the grid, feels, re-checks, reports cells."""

    name = "virtual_palpator"
    virtual = True
    PARAMS = (
        Param("depth_mm", 4.0, 0.2, 20.0, unit="mm", source="CHOSEN: ~2 N on the sponge, the controllers' range"),
        Param("checkpoints", (0.4, 0.6, 0.8, 1.0), kind=tuple, source="CHOSEN: fractions of the target depth"),
        Param("depth_cv", 0.08, 0.0, 0.5, source="CHOSEN: press-to-press variability of depth"),
        Param("aim_sd_mm", 2.0, 0.0, 10.0, unit="mm", source="CHOSEN: scatter of the probe about the cell centre"),
        Param("press_speed_mm_s", 6.0, 0.5, 100.0, unit="mm/s", source="CHOSEN: indentation speed"),
        Param("hold_s", 0.4, 0.0, 5.0, unit="s", source="CHOSEN"),
        Param("move_s", 0.3, 0.02, 5.0, unit="s", source="CHOSEN: time to move to the next cell"),
        Param("balloon_threshold_psi", 0.3, 0.0, 20.0, unit="psi", source="CHOSEN: ≈2 kPa on the finger pad"),
        Param("balloon_weber", 0.10, 0.01, 2.0, source="CHOSEN: pressure/force discrimination 7-15 %"),
        Param("vibration_threshold_ms2", 0.2, 0.0, 20.0, unit="m/s²", source="CHOSEN: ~0.1 µm at 200 Hz is ~0.2 m/s²"),
        Param("vibration_weber", 0.25, 0.01, 2.0, source="CHOSEN: vibrotactile amplitude discrimination ~20-30 %"),
        Param("screen_z", 2.0, 0.0, 10.0, source="CHOSEN: re-probe above this (max over 10 channel-depth notes)"),
        Param("report_z", 3.5, 0.0, 10.0, source="CHOSEN: ~0.1 false reports per 49-cell sweep (10 notes per cell)"),
        Param("confirm_presses", 2, 0, 10, kind=int, source="CHOSEN"),
        Param("guesses", 3, 0, 20, kind=int, source="CHOSEN: the paper's trials had 3 tumours"),
        Param("cell_mm", 20.0, 1.0, 100.0, unit="mm", source="used when the trial's public info has no grid size"),
        Param("columns", 7, 1, 50, kind=int, source="used when the trial's public info has no grid"),
        Param("rows", 7, 1, 50, kind=int, source="used when the trial's public info has no grid"),
    )

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        checked = validate_params("virtual_palpator participant", params, self.PARAMS)
        super().__init__(checked)
        p = checked
        self.senses = {
            "balloon_psi": Sense("balloon pressure", p["balloon_threshold_psi"], p["balloon_weber"], "psi"),
            "vibration_ms2": Sense("vibration", p["vibration_threshold_ms2"], p["vibration_weber"], "m/s²"),
        }
        cps = tuple(checked["checkpoints"])
        if not cps or not all(isinstance(c, int | float) and 0 < c <= 1 for c in cps) or list(cps) != sorted(set(cps)):
            raise ModelParameterError(
                f"virtual_palpator participant: checkpoints {list(cps)} must be increasing fractions in (0, 1]"
            )
        self.checkpoints = tuple(float(c) for c in cps)
        self._note_keys = tuple(
            (ch, (ch, "peak"), tuple((c, (ch, f"{c:g}")) for c in self.checkpoints)) for ch in CHANNELS
        )
        # every (channel, note) a cell is scored on: the checkpoints of each channel, then the peaks
        self._keys = tuple((ch, f"{c:g}") for ch in CHANNELS for c in self.checkpoints) + tuple(
            (ch, "peak") for ch in CHANNELS
        )
        self._rng: np.random.Generator | None = None

    # -- trial --------------------------------------------------------------------------------------
    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        self._rng = rng
        self.info = info
        self.columns, self.rows, self.cell_mm, self.origin = _grid(info.public, self.params)
        self.evidence: dict[tuple[int, int], _CellEvidence] = {}
        self.reports: list[tuple[int, int]] = []
        self._plan: list[_Segment] = []
        self._phase = "sweep"
        self._pose = (self.origin[0] - 5.0, self.origin[1] - 5.0, -5.0)
        self._notes: dict[tuple[str, str], float] = {}
        self._belief_depth = 0.0
        self._pressing: _Segment | None = None
        self._ref: dict[tuple[str, str], float | None] | None = None  # normal-tissue reference, after the sweep
        self._finished = False
        for row in range(1, self.rows + 1):
            cols = range(1, self.columns + 1) if row % 2 else range(self.columns, 0, -1)  # boustrophedon
            for col in cols:
                self._queue_probe((col, row))
        self._seg_index = 0
        self._seg_t0 = 0.0

    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        if self._finished:
            return Action(requests=(Request("finish"),))
        self._note(percept)
        # Leave time to report before a time limit ends the trial.
        if t >= self.info.time_limit_s - 2.0 / max(self.info.rate_hz, 1.0) - 1.0:
            return self._decide_and_finish()
        while True:
            if self._seg_index >= len(self._plan):
                if self._phase == "sweep":
                    self._phase = "confirm"
                    self._queue_confirmations()
                    self._seg_t0 = t
                    if self._seg_index < len(self._plan):
                        continue
                return self._decide_and_finish()
            seg = self._plan[self._seg_index]
            elapsed = t - self._seg_t0
            if elapsed < seg.duration:
                break
            self._end_segment(seg)
            self._seg_t0 += seg.duration
            self._seg_index += 1
        frac = 0.0 if seg.duration <= 0 else min(max(elapsed / seg.duration, 0.0), 1.0)
        pose = _lerp(seg.start, seg.end, frac) if seg.kind == "move" else _press_pose(seg, elapsed)
        self._pose = pose
        # what the participant believes its depth is: the actual depth without its own motor error
        self._belief_depth = pose[2] / seg.scale if seg.kind == "press" else 0.0
        self._pressing = seg if seg.kind == "press" else None
        return Action(inputs={"x_mm": pose[0], "y_mm": pose[1], "depth_mm": pose[2]})

    # -- planning -----------------------------------------------------------------------------------
    def _queue_probe(self, cell: tuple[int, int]) -> None:
        rng = self._rng
        p = self.params
        cx = self.origin[0] + (cell[0] - 0.5) * self.cell_mm + p["aim_sd_mm"] * rng.standard_normal()
        cy = self.origin[1] + (cell[1] - 0.5) * self.cell_mm + p["aim_sd_mm"] * rng.standard_normal()
        scale = max(1.0 + p["depth_cv"] * rng.standard_normal(), 0.05)
        depth = p["depth_mm"] * scale
        last = self._plan[-1].end if self._plan else self._pose
        above = (cx, cy, -2.0)
        self._plan.append(_Segment("move", p["move_s"], (last[0], last[1], -2.0), above))
        ramp = depth / p["press_speed_mm_s"]
        self._plan.append(
            _Segment("press", 2 * ramp + p["hold_s"], above, (cx, cy, depth), cell, ramp, p["depth_mm"], scale)
        )

    def _note(self, percept: Mapping[str, Any]) -> None:
        """Note what the actuators deliver (this tick's percept is the feel at the previous tick's depth)."""
        seg = self._pressing
        if seg is None:
            return
        believed = self._belief_depth
        notes = self._notes
        for ch, peak_key, cp_keys in self._note_keys:
            v = percept.get(ch)
            v = float(v) if isinstance(v, int | float) and math.isfinite(v) else 0.0
            if v > notes.get(peak_key, 0.0) or peak_key not in notes:
                notes[peak_key] = v
            for c, ck in cp_keys:
                if ck not in notes and believed >= c * seg.intended - 1e-9:
                    notes[ck] = v

    def _end_segment(self, seg: _Segment) -> None:
        if seg.kind != "press":
            self._notes = {}
            return
        ev = self.evidence.setdefault(seg.cell, _CellEvidence())
        ev.presses += 1
        for key, value in self._notes.items():
            seen = self.senses[key[0]].observe(value, self._rng)
            if seen > 0:
                ev.felt[key] = ev.felt.get(key, 0) + 1
                ev.logs.setdefault(key, []).append(math.log(seen))
        self._notes = {}
        self._pressing = None

    def _reference(self) -> dict[tuple[str, str], float | None]:
        """Median log-percept over the swept cells per (channel, checkpoint); None when normal tissue is not felt.

        Also sets ``_felt_rate``: the share of cells felt at each note on the first press (add-one smoothed),
        the base rate for the "felt here but not on normal tissue" test.
        """
        ref: dict[tuple[str, str], float | None] = {}
        self._felt_rate = {}
        n = len(self.evidence)
        for key in self._keys:
            first = [ev.logs[key][0] if ev.logs.get(key) else -math.inf for ev in self.evidence.values()]
            med = float(np.median(first)) if first else -math.inf
            ref[key] = med if math.isfinite(med) else None
            felt = sum(1 for v in first if math.isfinite(v))
            self._felt_rate[key] = (felt + 1) / (n + 2)
        return ref

    def _score(self, ev: _CellEvidence, ref: dict[tuple[str, str], float | None]) -> float:
        """Evidence that a cell differs from normal tissue, in noise SDs of its mean (inf: felt only here)."""
        best = -math.inf
        for key in self._keys:
            sigma = self.senses[key[0]].sigma
            logs = ev.logs.get(key)
            if ref[key] is None:
                # normal tissue mostly not felt here: how surprising is being felt in k of n presses?
                k = ev.felt.get(key, 0)
                if k:
                    p_tail = float(stats.binom.sf(k - 1, ev.presses, self._felt_rate[key]))
                    best = max(best, float(stats.norm.isf(max(p_tail, 1e-300))))
                continue
            if not logs:
                continue
            best = max(best, (float(np.mean(logs)) - ref[key]) / (sigma / math.sqrt(len(logs))))
        return best

    def _queue_confirmations(self) -> None:
        ref = self._reference()
        self._ref = ref
        candidates = [cell for cell, ev in self.evidence.items() if self._score(ev, ref) > self.params["screen_z"]]
        for cell in candidates:
            for _ in range(self.params["confirm_presses"]):
                self._queue_probe(cell)

    def _decide_and_finish(self) -> Action:
        if self._finished:
            return Action(requests=(Request("finish"),))
        ref = self._ref or self._reference()
        scored = sorted(
            ((self._score(ev, ref), cell) for cell, ev in self.evidence.items()),
            key=lambda sc: (-sc[0], sc[1]),
        )
        chosen: list[tuple[int, int]] = []
        for score, cell in scored:
            if score <= self.params["report_z"]:
                break
            if all(max(abs(cell[0] - c[0]), abs(cell[1] - c[1])) > 1 for c in chosen):
                chosen.append(cell)
        if not chosen and self.params["guesses"]:
            cells = [(c, r) for r in range(1, self.rows + 1) for c in range(1, self.columns + 1)]
            idx = self._rng.choice(len(cells), size=min(self.params["guesses"], len(cells)), replace=False)
            chosen = [cells[i] for i in sorted(idx)]
        self.reports = chosen
        self._finished = True
        requests = tuple(Request("report", {"column": c, "row": r}) for c, r in chosen) + (Request("finish"),)
        return Action(inputs={"x_mm": self._pose[0], "y_mm": self._pose[1], "depth_mm": -5.0}, requests=requests)


def _lerp(a, b, f):
    return tuple(x + (y - x) * f for x, y in zip(a, b, strict=True))


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


def _grid(public: Mapping[str, Any], params: Mapping[str, Any]) -> tuple[int, int, float, tuple[float, float]]:
    """Grid size from the trial's public info (scene ``grid`` or the report spec), else the parameters."""
    grid = public.get("grid") if isinstance(public, Mapping) else None
    if isinstance(grid, Mapping):
        try:
            origin = tuple(float(v) for v in grid.get("origin_mm", (0.0, 0.0)))
            return int(grid["columns"]), int(grid["rows"]), float(grid["cell_mm"]), origin  # type: ignore[return-value]
        except (KeyError, TypeError, ValueError):
            raise ModelParameterError(f"virtual_palpator: the trial's grid {dict(grid)!r} is incomplete") from None
    report = public.get("report") if isinstance(public, Mapping) else None
    if isinstance(report, Mapping) and report.get("columns") and report.get("rows"):
        return len(report["columns"]), len(report["rows"]), float(params["cell_mm"]), (0.0, 0.0)
    return int(params["columns"]), int(params["rows"]), float(params["cell_mm"]), (0.0, 0.0)
