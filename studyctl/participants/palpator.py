"""A virtual participant who palpates the sponge phantom cell by cell and reports where tumours feel different.

It knows only what a participant knows (the grid, from ``TrialInfo.public``), what the actuators deliver
(``balloon_psi`` and ``vibration_ms2`` from the device's feedback) and, when the condition shows the camera
view, how far the probe tip really sank into the sponge (``view.depth_mm``). Each is sensed through a noisy
Weber observer (:class:`studyctl.models.perception.Sense`). It never sees the scene or the tumour sites, so
whether it finds a tumour depends on the controller turning a stiffer spot into a feelable difference — or,
without haptic feedback, on seeing the instrument yield more over a stiffer spot.

Behaviour (the paper's instructions: "follow the grid, checking each location one by one", least force,
as quickly as possible):

1. **Sweep**: for every cell in raster order, move above the cell (aim noise), press towards the intended
   depth at the person's speed (depth noise: the participant believes it pressed to the intended depth),
   hold, release. A press stops early when a haptic cue feels firm enough (``stop_balloon_psi``,
   ``stop_vibration_ms2``, felt with the person's Weber noise each press: "least force"), so how hard a person
   presses follows from what each controller delivers, not from the condition: the bio-inspired balloon gives
   10-16 psi from 0.3-0.6 N, the linear one reaches 13 psi near 1.6 N, the piecewise one tops out at 11 psi.
   With ``stop_min_seen_mm`` a cue only ends a press once the endoscope shows the tip has dented the sponge
   that deep (seen with the person's visual Weber noise): a balloon already strong at touch-down then no longer
   ends presses at contact.
   How far the hand went before the cue said enough is itself noted (less travel over stiffer tissue: with a
   force target the travel is the stiffness cue, ``travel_weber``). What the person does with the time a stopped
   press saved is ``after_stop``: release and go on, hold, or tap the same spot again (``max_taps``).
   With ``lift_rule: settled`` a press is held past its planned hold while a felt cue still rises (the balloon's
   fill lags the force), at most ``settle_max_s``.
   What the balloon and the motor deliver is noted when the believed depth passes each checkpoint and at
   its strongest; the camera's tip depth is noted at the bottom of the press as the ratio of the hand's
   (believed) depth to the seen depth (the instrument yields more on stiffer tissue). Each note is one
   observation with Weber noise and a detection threshold.
2. **Screen**: for each note the reference is the median over all cells (normal tissue); a cell whose mean
   log-percept exceeds it by ``screen_z`` noise SDs of the mean (or, where normal tissue is mostly not felt,
   that is felt — or stopped on — more often than the base rate allows, as a z-score) is re-probed
   ``confirm_presses`` times; cells still undecided are probed again, up to ``confirm_rounds`` rounds. With
   ``sure_odds`` (after practice, odds rule) a cell already that sure after the sweep is not re-probed; with
   ``dismiss_odds`` a cell is dropped only once a tumour there is that unlikely (the two bounds of Wald's sequential
   test), not below the fixed ``screen_z``.
3. **Report**: cells whose evidence stays above ``report_z``, keeping only the strongest of neighbouring
   cells; then ``finish``. When nothing stood out, it reports ``guesses`` cells: distinct random ones, or with
   ``guess: best`` those whose evidence was strongest (a forced choice by the max rule).

**Familiarisation** (``familiarise``, off by default): the paper gave each subject up to 5 min before each trial on an
example phantom with the 3 tumour sites marked. With it on, the engine runs that time as a practice through the
condition's device and controller (``info.public["practice"]``, the marks in ``info.public["marks"]``): the person
presses each mark and as many plain cells ``practice_presses`` times, learns which notes told tumour from sponge and
by how much (:mod:`studyctl.participants.palpator_practice`), and in the trial that follows judges each cell by those
notes weighted together instead of by its strongest note; with ``report_rule: odds`` it then reports a cell when the
practice makes a tumour there likelier than not (the criterion from the separation it learnt and the 3 marked of 49
cells), not at the fixed ``report_z``.

Between people, every perceptual, motor and decision parameter may differ (a population file draws them);
within a person, the press speed varies from trial to trial (``speed_trial_cv``) and the depth from press to
press (``depth_cv``), and perceptual noise shrinks with practice over trials (``learning``).

This module holds the plugin (its name, parameters, memory) and the trial's loop. The rest has its own module: the
parameters (:mod:`.palpator_params`), the probe's motion (:mod:`.palpator_press`: segments, presses and taps queued
with their own noise, when a press stops), what a press is noted and felt as (:mod:`.palpator_perception`), the
reference, scores and reports (:mod:`.palpator_decision`) and the practice (:mod:`.palpator_practice`). They are
mixins of one object that holds the trial's state, as in the tissue palpator: a trial draws from one random stream
in one order (probes are queued by the sweep, the re-probing and the taps alike), which the pinned seed-000
sessions depend on.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.models.perception import Sense
from studyctl.participants.palpator_decision import CellDecision, _scipy_stats
from studyctl.participants.palpator_params import NEVER, PARAMS
from studyctl.participants.palpator_perception import STOP, TRAVEL, VISUAL, PressNotes, _CellEvidence
from studyctl.participants.palpator_practice import CueWeights, Familiarisation
from studyctl.participants.palpator_press import CHANNELS, PressPlanning, _lerp, _press_pose, _Segment, _stop_press
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo
from studyctl.plugins.params import Param, validate_params


class VirtualPalpator(PressPlanning, PressNotes, CellDecision, Familiarisation, Participant):
    """Virtual participant for the sponge-phantom study: sweeps the grid, feels, re-checks, reports cells."""

    name = "virtual_palpator"
    virtual = True
    PARAMS: ClassVar[tuple[Param, ...]] = PARAMS

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        # scipy.stats is imported here, before any trial loop, not at module import (test collection) and not at
        # the first report mid-trial: that import takes ~1 s, a stall of the real-time loop in a rehearsal on
        # emulated hardware (the board's output watchdog trips).
        _scipy_stats()
        checked = validate_params("virtual_palpator participant", params, self.PARAMS)
        super().__init__(checked)
        p = checked
        self.base_senses = {
            "balloon_psi": Sense("balloon pressure", p["balloon_threshold_psi"], p["balloon_weber"], "psi"),
            "vibration_ms2": Sense("vibration", p["vibration_threshold_ms2"], p["vibration_weber"], "m/s²"),
            "view": Sense("tip depth", 0.0, p["visual_weber"], "mm"),
            "travel": Sense("hand travel", 0.0, p["travel_weber"], "mm"),
        }
        self.senses = dict(self.base_senses)
        cps = tuple(checked["checkpoints"])
        if not cps or not all(isinstance(c, int | float) and 0 < c <= 1 for c in cps) or list(cps) != sorted(set(cps)):
            raise ModelParameterError(
                f"virtual_palpator participant: checkpoints {list(cps)} must be increasing fractions in (0, 1]"
            )
        self.checkpoints = tuple(float(c) for c in cps)
        self._note_keys = tuple(
            (ch, (ch, "peak"), tuple((c, (ch, f"{c:g}")) for c in self.checkpoints)) for ch in CHANNELS
        )
        # every (channel, note) a cell is scored on: the checkpoints of each channel, the peaks, the camera
        self._keys = tuple((ch, f"{c:g}") for ch in CHANNELS for c in self.checkpoints) + tuple(
            (ch, "peak") for ch in CHANNELS
        ) + (VISUAL, STOP, TRAVEL)
        self._stop = {"balloon_psi": p["stop_balloon_psi"], "vibration_ms2": p["stop_vibration_ms2"]}
        self._stop_ratio = float(p["stop_ratio"])
        self._stop_by_depth = p["stop_match"] == "depth"
        self._stop_levels = any(v < NEVER for v in self._stop.values())  # an absolute "enough" level is in use
        if p["guess"] not in ("random", "best"):
            raise ModelParameterError(f"virtual_palpator participant: guess {p['guess']!r} must be random or best")
        if p["after_stop"] not in ("release", "hold", "tap"):
            raise ModelParameterError(f"virtual_palpator participant: after_stop {p['after_stop']!r} must be "
                                      "release, hold or tap")
        if 0 < p["sure_odds"] < 1:
            raise ModelParameterError(f"virtual_palpator participant: sure_odds {p['sure_odds']} must be 0 (off) or "
                                      "at least 1 (a tumour at least as likely as not: the report level or beyond)")
        self._settles = p["lift_rule"] == "settled"
        self._rng: np.random.Generator | None = None
        self.trials_done = 0
        self.practises = bool(p["familiarise"])  # the engine runs the familiarisation as a practice for this person
        self.cues: CueWeights | None = None  # learnt in the last practice: applies to the trial that follows it

    # -- memory (what carries over between trials: practice) ----------------------------------------------
    def memory(self) -> Mapping[str, Any]:
        out: dict[str, Any] = {"trials_done": self.trials_done}
        if self.cues is not None:
            out["cues"] = self.cues.to_json()
        return out

    def recall(self, memory: Mapping[str, Any]) -> None:
        self.trials_done = int(memory.get("trials_done", 0))
        cues = memory.get("cues")
        self.cues = CueWeights.from_json(cues) if isinstance(cues, Mapping) else None

    # -- trial --------------------------------------------------------------------------------------
    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        self._rng = rng
        self.info = info
        p = self.params
        self._practice = bool(info.public.get("practice")) if isinstance(info.public, Mapping) else False
        # Practice: perceptual noise shrinks over the first trials (Weber fractions scale down); the example
        # phantom's practice is not a trial (the learning trait counts trials, as fitted).
        gain = 1.0 - p["learning"] * min(self.trials_done, 3) / 3.0
        self.senses = {k: Sense(s.name, s.threshold, s.weber * gain, s.unit) for k, s in self.base_senses.items()}
        if not self._practice:
            self.trials_done += 1
        # Within-person pace of this trial.
        self._pace = max(1.0 + p["speed_trial_cv"] * rng.standard_normal(), 0.3)
        self._tick_s = 1.0 / max(info.rate_hz, 1.0)
        self._report_by_s = info.time_limit_s - 2.0 / max(info.rate_hz, 1.0) - 1.0  # act() compares it every tick
        self._settle_ticks = max(round(p["settle_s"] / self._tick_s), 1)
        self.columns, self.rows, self.cell_mm, self.origin = _grid(info.public, p)
        self.evidence: dict[tuple[int, int], _CellEvidence] = {}
        self.reports: list[tuple[int, int]] = []
        self._plan: list[_Segment] = []
        self._phase = "sweep"
        self._pose = (self.origin[0] - 5.0, self.origin[1] - 5.0, -5.0)
        self._notes: dict[tuple[str, str], float] = {}
        self._belief_depth = 0.0
        self._pressing: _Segment | None = None
        self._ref: dict[tuple[str, str], float | None] | None = None  # normal-tissue reference, after the sweep
        self._spread: dict[tuple[str, str], float] = {}  # how much each note varies over plain tissue
        self._peaks: dict[str, list[float]] = {ch: [] for ch in CHANNELS}  # strongest feel of each press so far
        self._usual: dict[str, float] = {}  # their running median: what pressing normal tissue feels like
        self._plain_at: dict[tuple[str, str], list[float]] = {}  # stop_match depth: each checkpoint's feel so far
        self._usual_at: dict[tuple[str, str], float] = {}  # ... and its running median
        self._finished = False
        self._rounds = 0  # rounds of re-probing done
        self._press_logs: list[tuple[tuple[int, int], dict[tuple[str, str], float]]] = []  # practice: each press
        self._ref_combined: float | None = None
        if self._practice:
            self._queue_practice(info.public.get("marks") or ())
        else:
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
        if t >= self._report_by_s:  # (a practice that reaches its limit still learns from what it pressed)
            return self._learn_and_finish() if self._practice else self._decide_and_finish()
        while True:
            if self._seg_index >= len(self._plan) and self._practice:
                if self._practise_more(t):
                    self._seg_t0 = t
                    continue
                return self._learn_and_finish()
            if self._seg_index >= len(self._plan):
                more = self._phase == "confirm" and self._rounds < self.params["confirm_rounds"]
                if self._phase == "sweep" or more:
                    first = self._phase == "sweep"
                    self._phase = "confirm"
                    self._rounds += 1
                    self._queue_confirmations(first)
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
        if seg.kind == "press":
            if (not seg.stopped and elapsed < seg.ramp and self._dented(percept, seg)
                    and self._strong(percept, seg.stop_gain)):
                planned = seg.duration
                _stop_press(seg, elapsed, keep_tempo=self.params["after_stop"] == "hold")
                if self.params["after_stop"] == "tap" and not seg.retap:
                    self._queue_taps(seg, planned - seg.duration)
            elif self.params["look_s"] > 0 and not seg.looked and elapsed >= seg.duration - seg.ramp:
                # about to release: with nothing felt, look at the instrument a little longer
                seg.looked = True
                if not any(self._notes.get((ch, "peak"), 0.0) > 0 for ch in CHANNELS):
                    seg.duration += self.params["look_s"]
                    seg.lift = "looked"
            if self._settles:
                self._hold_while_rising(seg, elapsed, percept)
        if seg.kind == "press":
            pose = _press_pose(seg, elapsed)
            # what the participant believes its depth is: the actual depth without its own motor error
            self._belief_depth = pose[2] / seg.scale
            self._pressing = seg
        else:
            frac = 0.0 if seg.duration <= 0 else min(max(elapsed / seg.duration, 0.0), 1.0)
            pose = _lerp(seg.start, seg.end, frac)
            self._belief_depth = 0.0
            self._pressing = None
        self._pose = pose
        return Action(inputs={"x_mm": pose[0], "y_mm": pose[1], "depth_mm": pose[2]})


    def _hold_while_rising(self, seg: _Segment, elapsed: float, percept: Mapping[str, Any]) -> None:
        """``lift_rule: settled``: about to release, stay at the bottom one more tick while a felt cue still rises."""
        seg.trace.append(tuple(float(percept.get(ch) or 0.0) for ch in CHANNELS))
        if (elapsed >= seg.duration - seg.ramp and seg.held < self.params["settle_max_s"] - 1e-9
                and self._rising(seg)):
            step = self._tick_s
            seg.duration += step
            seg.held += step
            seg.lift = "settled"


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
