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
   What the balloon and the motor deliver is noted when the believed depth passes each checkpoint and at
   its strongest; the camera's tip depth is noted at the bottom of the press as the ratio of the hand's
   (believed) depth to the seen depth (the instrument yields more on stiffer tissue). Each note is one
   observation with Weber noise and a detection threshold.
2. **Screen**: for each note the reference is the median over all cells (normal tissue); a cell whose mean
   log-percept exceeds it by ``screen_z`` noise SDs of the mean (or, where normal tissue is mostly not felt,
   that is felt — or stopped on — more often than the base rate allows, as a z-score) is re-probed
   ``confirm_presses`` times; cells still undecided are probed again, up to ``confirm_rounds`` rounds.
3. **Report**: cells whose evidence stays above ``report_z``, keeping only the strongest of neighbouring
   cells; then ``finish``. When nothing stood out, it reports ``guesses`` cells: distinct random ones, or with
   ``guess: best`` those whose evidence was strongest (a forced choice by the max rule).

**Familiarisation** (``familiarise``, off by default): the paper gave each subject up to 5 min before each trial on an
example phantom with the 3 tumour sites marked. With it on, the engine runs that time as a practice through the
condition's device and controller (``info.public["practice"]``, the marks in ``info.public["marks"]``): the person
presses each mark and as many plain cells ``practice_presses`` times, learns which notes told tumour from sponge and
by how much (:mod:`studyctl.participants.palpator_practice`), and in the trial that follows judges each cell by those
notes weighted together instead of by its strongest note.

Between people, every perceptual, motor and decision parameter may differ (a population file draws them);
within a person, the press speed varies from trial to trial (``speed_trial_cv``) and the depth from press to
press (``depth_cv``), and perceptual noise shrinks with practice over trials (``learning``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.models.perception import Sense
from studyctl.participants.palpator_practice import CueWeights, learn_cue_weights
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo
from studyctl.plugins.params import Param, validate_params

CHANNELS = ("balloon_psi", "vibration_ms2")
VISUAL = ("view", "yield")  # the note key of the camera cue: hand depth / seen tip depth at the bottom
STOP = ("stop", "early")  # the note key of a press stopped by a strong sensation
NEVER = 30.0  # a stop level this high is never reached (the regulator gives ≤ 20 psi, the motor ≤ 12 m/s²)
TRAVEL = ("travel", "stop")  # the note key of how far the hand went before the feedback said enough (log 1/depth)


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
    stopped: bool = False  # ended early by a strong sensation
    stop_gain: float = 1.0  # this press's felt-strength noise on the stop levels (Weber noise of the magnitude)
    seen_gain: float = 1.0  # this press's visual noise on the minimum dent seen before a stop (stop_min_seen_mm)
    retap: bool = False  # an extra tap after a stopped press (it makes no taps of its own)
    looked: bool = False  # the dwell to judge by eye has been decided


@dataclass
class _CellEvidence:
    logs: dict[tuple[str, str], list[float]] = field(default_factory=dict)  # (channel, checkpoint) -> log percepts
    felt: dict[tuple[str, str], int] = field(default_factory=dict)
    presses: int = 0
    combined: list[float] = field(default_factory=list)  # each press's evidence by the cue weights learnt in practice


def _scipy_stats():  # noqa: ANN202 - the scipy.stats module
    from scipy import stats  # noqa: PLC0415 - about a second to import: see VirtualPalpator.__init__

    return stats


class VirtualPalpator(Participant):
    """Virtual participant for the sponge-phantom study: sweeps the grid, feels, re-checks, reports cells."""

    name = "virtual_palpator"
    virtual = True
    PARAMS = (
        # -- motor ----------------------------------------------------------------------------------------
        Param("depth_mm", 4.0, 0.2, 20.0, unit="mm", source="FITTED: intended press depth (~2 N on the sponge; "
              "Pugh 2015: examiners differ widely in palpation force)"),
        Param("checkpoints", (0.4, 0.6, 0.8, 1.0), kind=tuple, source="CHOSEN: fractions of the target depth "
              "at which the feel is noted"),
        Param("depth_cv", 0.08, 0.0, 0.5, source="CHOSEN: press-to-press variability of depth (motor noise)"),
        Param("aim_sd_mm", 2.0, 0.0, 10.0, unit="mm", source="CHOSEN: scatter of the probe about the cell centre"),
        Param("press_speed_mm_s", 6.0, 0.5, 100.0, unit="mm/s", source="FITTED: indentation speed"),
        Param("speed_trial_cv", 0.10, 0.0, 1.0, source="CHOSEN: trial-to-trial variation of a person's pace "
              "(speed and move time), within person"),
        Param("hold_s", 0.4, 0.0, 5.0, unit="s", source="FITTED: dwell at the bottom of a press"),
        Param("move_s", 0.3, 0.02, 5.0, unit="s", source="FITTED: time to move to the next 20 mm cell "
              "(Fitts-type pointing with a robot master, ~0.3-1 s)"),
        Param("stop_balloon_psi", 30.0, 0.0, 30.0, unit="psi", source="FITTED: a balloon pressure felt as firm "
              "enough ends the descent (instruction: least force; a person presses until the feedback says enough, "
              "so a cue that grows early, as the bio-inspired balloon does, ends presses at a lower force); felt "
              "with the person's balloon Weber noise per press; 30 = never (the regulator gives ≤ 20)"),
        Param("stop_vibration_ms2", 30.0, 0.0, 30.0, unit="m/s²", source="FITTED: as stop_balloon_psi for "
              "vibration; 30 = never (the motor gives ≤ 12)"),
        Param("stop_min_seen_mm", 0.0, 0.0, 10.0, unit="mm", source="CHOSEN: a haptic cue only ends a press once "
              "the endoscope shows the tip has dented the sponge at least this deep (felt with the person's visual "
              "Weber noise each press): people press until they see contact, then stop where the feedback says "
              "enough, so a cue that is already strong at touch-down does not end a press before the tissue "
              "under the probe has been deformed (0 = no visual minimum; without a view the hand's believed depth "
              "is used)"),
        Param("stop_ratio", 0.0, 0.0, 10.0, source="FITTED: a press also stops when a cue exceeds this multiple of "
              "what normal tissue gave at its strongest (the running median of earlier presses; 0 = never): "
              "something under the probe already feels different, so pressing on only adds force"),
        Param("after_stop", "release", kind=str, source="CHOSEN: what a person does with the rest of a press's "
              "planned time when a strong cue ended the descent early: release (go on), hold (stay at that depth) "
              "or tap (re-probe the same spot, each tap ending where the cue says enough: feedback felt during "
              "the dynamic phase invites probing, paper §IV; people palpate at a steady rhythm, and the paper "
              "found no effect of the feedback on completion time, p = 0.684)"),
        Param("max_taps", 2, 0, 10, kind=int, source="CHOSEN: most extra taps after one stopped press"),
        Param("look_s", 0.0, 0.0, 5.0, unit="s", source="FITTED: extra dwell to judge the instrument's yield by eye "
              "when a press gave no haptic sensation (visual judgement of deformation takes time)"),
        # -- perception -----------------------------------------------------------------------------------
        Param("balloon_threshold_psi", 0.19, 0.0, 20.0, unit="psi",
              source="CITED: static one-point pressure threshold of the index finger 0.13 ± 0.06 g/mm² "
                     "(= 0.19 ± 0.09 psi, CV 46 %, n = 35; research/virtual_participants.md §1)"),
        Param("balloon_weber", 0.10, 0.01, 2.0,
              source="CITED: force JND 7 % (Pang 1991), 10 % (Allin 2002), 18-19 % passive (Gueorguiev 2020)"),
        Param("vibration_threshold_ms2", 0.2, 0.0, 20.0, unit="m/s²",
              source="CITED: ~0.1 µm at 150-250 Hz (Brisben 1999; Verrillo) = 0.16-0.25 m/s²; varies with age"),
        Param("vibration_weber", 0.20, 0.01, 2.0, source="CITED: vibrotactile amplitude discrimination ≈ 20 %"),
        Param("visual_weber", 0.10, 0.01, 2.0,
              source="CITED: visual speed Weber ≈ 7 % (Vision Res 1988), pseudo-haptic stiffness JND 6-13.4 % "
                     "(Lécuyer); fractions vary considerably between people (J Vis 2018)"),
        Param("travel_weber", 0.22, 0.01, 2.0,
              source="CITED: compliance resolution 22 % once work and terminal-force cues are separated (Tan, "
                     "Durlach, Beauregard & Srinivasan 1995, Percept Psychophys 57:495): with a force target the "
                     "hand's travel is the stiffness cue (Fu, van Paassen & Mulder 2017)"),
        Param("visual_trust", 1.0, 0.0, 1.0, source="FITTED: weight a person gives the camera cue (0 ignores it)"),
        Param("learning", 0.0, 0.0, 0.8, source="CITED: most practice gain in lump detection comes within 1-2 "
              "sessions (Adams et al.); fraction of perceptual noise lost by the 4th trial"),
        # -- decision -------------------------------------------------------------------------------------
        Param("judge_spread", False, kind=bool, source="CHOSEN: whether a cell's evidence is judged against how "
              "much normal tissue varied over the survey (the robust SD of the first presses' percepts) when that "
              "exceeds the senses' own noise: in signal detection the criterion is set against the total noise of "
              "the non-signal stimuli, external and internal (Green & Swets 1966; Lu & Dosher 2008, external noise); "
              "a feedback that varies from press to press on plain sponge (the hand's depth varies by depth_cv) "
              "marks fewer plain cells as different. False: only the Weber noise of the senses"),
        Param("screen_z", 2.0, 0.0, 10.0, source="FITTED: re-probe a cell whose evidence exceeds this"),
        Param("report_z", 3.5, 0.0, 10.0, source="FITTED: confidence needed to report a cell"),
        Param("confirm_presses", 2, 0, 10, kind=int, source="CHOSEN: re-probes of a candidate cell"),
        Param("confirm_rounds", 1, 1, 10, kind=int, source="CHOSEN: a candidate whose evidence is still between "
              "screen_z and report_z after a round of re-probes is probed again, up to this many rounds "
              "(sequential sampling: weak cues are checked more often, Wald 1947); 1 = one round"),
        Param("max_reports", 0, 0, 49, kind=int, source="CHOSEN: at most this many cells are reported, the strongest "
              "first (0 = no limit); the example phantom shows 3 tumours, so people expect about that many"),
        Param("guess", "random", kind=str, source="CHOSEN: which cells a person reports when nothing stood out: "
              "random (distinct cells at random) or best (the cells whose evidence was strongest: in a forced choice "
              "an observer picks the alternative with the largest observation, the max rule of signal detection "
              "theory, Green & Swets 1966; the instruction was to report the tumours, so weak evidence still "
              "guides where)"),
        Param("familiarise", False, kind=bool, source="CITED: before each trial the paper's subjects had up to 5 min "
              "on an example phantom with the 3 tumour sites marked, to get used to the feedback (Methods II.D.3). "
              "True: the person practises there through the condition's device and controller (the engine's practice "
              "run), pressing each marked site and plain sponge practice_presses times, and then judges cells by the "
              "cues that told tumour from sponge, weighted by how much and how reliably they did "
              "(studyctl.participants.palpator_practice). False: no practice; cells judged by their strongest cue"),
        Param("practice_presses", 4, 1, 20, kind=int, source="CHOSEN: presses on each marked site in practice (and as "
              "many on plain sponge, at different cells); 3 sites x 4 + 12 plain presses take ~20 s of the 5 min"),
        Param("guesses", 3, 0, 20, kind=int, source="CHOSEN: cells reported when nothing stood out (the paper's "
              "trials had 3 tumours; subjects were told to report)"),
        Param("cell_mm", 20.0, 1.0, 100.0, unit="mm", source="used when the trial's public info has no grid size"),
        Param("columns", 7, 1, 50, kind=int, source="used when the trial's public info has no grid"),
        Param("rows", 7, 1, 50, kind=int, source="used when the trial's public info has no grid"),
    )

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
        self._stop_levels = any(v < NEVER for v in self._stop.values())  # an absolute "enough" level is in use
        if p["guess"] not in ("random", "best"):
            raise ModelParameterError(f"virtual_palpator participant: guess {p['guess']!r} must be random or best")
        if p["after_stop"] not in ("release", "hold", "tap"):
            raise ModelParameterError(f"virtual_palpator participant: after_stop {p['after_stop']!r} must be "
                                      "release, hold or tap")
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
        if t >= self.info.time_limit_s - 2.0 / max(self.info.rate_hz, 1.0) - 1.0:
            return self._decide_and_finish()
        while True:
            if self._seg_index >= len(self._plan) and self._practice:
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
        frac = 0.0 if seg.duration <= 0 else min(max(elapsed / seg.duration, 0.0), 1.0)
        pose = _lerp(seg.start, seg.end, frac) if seg.kind == "move" else _press_pose(seg, elapsed)
        self._pose = pose
        # what the participant believes its depth is: the actual depth without its own motor error
        self._belief_depth = pose[2] / seg.scale if seg.kind == "press" else 0.0
        self._pressing = seg if seg.kind == "press" else None
        return Action(inputs={"x_mm": pose[0], "y_mm": pose[1], "depth_mm": pose[2]})

    # -- planning -----------------------------------------------------------------------------------
    def _queue_practice(self, marks: Any) -> None:
        """Press each marked site and as many plain cells (two cells or more from every mark), practice_presses
        times each site; the marks are drawn on the example phantom (positions, or their grid cells)."""
        n = self.params["practice_presses"]
        sites = []
        for m in marks:
            xy = (m.get("x_mm"), m.get("y_mm")) if isinstance(m, Mapping) else (None, None)
            if all(isinstance(v, int | float) for v in xy):
                x, y = float(m["x_mm"]), float(m["y_mm"])
                cell = (int(math.floor((x - self.origin[0]) / self.cell_mm)) + 1,
                        int(math.floor((y - self.origin[1]) / self.cell_mm)) + 1)
                sites.append((cell, (x, y)))
        if not sites:
            raise ModelParameterError("virtual_palpator: the practice phantom shows no marks (x_mm, y_mm of each "
                                      "marked site in the trial's public 'marks'); familiarise needs them")
        self._marked = {cell for cell, _ in sites}
        plain = [(c, r) for r in range(1, self.rows + 1) for c in range(1, self.columns + 1)
                 if all(max(abs(c - m[0]), abs(r - m[1])) >= 2 for m in self._marked)]
        for cell, at in sites:
            for _ in range(n):
                self._queue_probe(cell, at)
        count = min(n * len(sites), len(plain))
        for i in sorted(self._rng.choice(len(plain), size=count, replace=False)):
            self._queue_probe(plain[i])

    def _learn_and_finish(self) -> Action:
        """End of practice: learn the cue weights from the presses on the marks and on plain sponge, then finish."""
        tumour = [logs for cell, logs in self._press_logs if cell in self._marked]
        plain = [logs for cell, logs in self._press_logs if cell not in self._marked]
        floor = {ch: sense.sigma**2 for ch, sense in self.senses.items()}
        floor[VISUAL[0]] = self.senses["view"].sigma ** 2
        self.cues = learn_cue_weights(tumour, plain, floor)
        self._finished = True
        return Action(inputs={"x_mm": self._pose[0], "y_mm": self._pose[1], "depth_mm": -5.0},
                      requests=(Request("finish"),))

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
        usual = self._usual
        for ch, level in self._stop.items():
            v = percept.get(ch)
            if isinstance(v, int | float) and (v * gain >= level or (ratio and usual.get(ch, 0.0) > 0
                                                              and v >= ratio * usual[ch])):
                return True
        return False

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
        view = percept.get("view")
        if isinstance(view, Mapping) and believed > 0:
            seen = view.get("depth_mm")
            # at the deepest point of the press: the hand's depth against the tip depth the camera shows
            if isinstance(seen, int | float) and seen > 0 and believed >= notes.get(("view", "hand"), 0.0):
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
        if self._practice:
            self._press_logs.append((seg.cell, press))
        elif self.cues is not None:
            combined = self.cues.combine(press)
            if combined is not None:
                ev.combined.append(combined)
        elif self._stop_ratio:
            for ch in CHANNELS:  # only unstopped presses show what pressing all the way usually feels like
                peaks = self._peaks[ch]
                peaks.append(notes.get((ch, "peak"), 0.0))
                if len(peaks) >= 5:
                    self._usual[ch] = float(np.median(peaks))
        self._notes = {}
        self._pressing = None

    def _reference(self) -> dict[tuple[str, str], float | None]:
        """Median log-percept over the swept cells per (channel, checkpoint); None when normal tissue is not felt.

        Also sets ``_felt_rate``: the share of cells felt at each note on the first press (add-one smoothed),
        the base rate for the "felt here but not on normal tissue" test, and ``_spread``: the robust SD of the
        first-press log-percepts over the cells (how much pressing normal tissue varies, noise of the senses,
        of the hand's depth and of the feedback itself together), used with ``judge_spread``.
        """
        ref: dict[tuple[str, str], float | None] = {}
        self._felt_rate = {}
        self._spread = {}
        n = len(self.evidence)
        for key in self._keys:
            first = [ev.logs[key][0] if ev.logs.get(key) else -math.inf for ev in self.evidence.values()]
            med = float(np.median(first)) if first else -math.inf
            ref[key] = med if math.isfinite(med) and key != STOP else None
            felt_logs = np.array([v for v in first if math.isfinite(v)])
            if ref[key] is not None and felt_logs.size >= 5:
                # how much normal tissue itself varies from press to press (robust SD: 1.4826 x MAD)
                self._spread[key] = 1.4826 * float(np.median(np.abs(felt_logs - ref[key])))
            felt = sum(1 for ev in self.evidence.values() if ev.felt.get(key, 0)) if key == STOP else sum(
                1 for v in first if math.isfinite(v))
            self._felt_rate[key] = (felt + 1) / (n + 2)
        firsts = [ev.combined[0] for ev in self.evidence.values() if ev.combined]
        # what plain sponge gives by the learnt cues in this trial: the median over the surveyed cells
        self._ref_combined = float(np.median(firsts)) if firsts else None
        return ref

    def _score(self, ev: _CellEvidence, ref: dict[tuple[str, str], float | None]) -> float:
        """Evidence that a cell differs from normal tissue, in noise SDs of its mean (inf: felt only here).

        After practice (``familiarise``): the combined evidence of the learnt cues against this trial's plain
        level, in SDs of its mean (the practice's plain-sponge spread over the cell's presses)."""
        if self.cues is not None:
            if not ev.combined or self._ref_combined is None:
                return -math.inf
            return (float(np.mean(ev.combined)) - self._ref_combined) / (self.cues.spread / math.sqrt(len(ev.combined)))
        stats = _scipy_stats()
        best = -math.inf
        for key in self._keys:
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
            sigma = self.senses[key[0]].sigma
            if self.params["judge_spread"]:
                sigma = max(sigma, self._spread.get(key, 0.0))
            z = (float(np.mean(logs)) - ref[key]) / (sigma / math.sqrt(len(logs)))
            if key == VISUAL:
                z *= self.params["visual_trust"]
            best = max(best, z)
        return best

    def _queue_confirmations(self, first: bool = True) -> None:
        """Re-probe the cells that stood out; after the first round only those still undecided (evidence between
        screen_z and report_z)."""
        if first:
            self._ref = self._reference()
        ref = self._ref
        p = self.params
        candidates = [cell for cell, ev in self.evidence.items()
                      if p["screen_z"] < self._score(ev, ref) and (first or self._score(ev, ref) <= p["report_z"])]
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
                if len(chosen) == self.params["max_reports"]:
                    break
        if not chosen and self.params["guesses"]:
            chosen = self._guess(scored)
        self.reports = chosen
        self._finished = True
        requests = tuple(Request("report", {"column": c, "row": r}) for c, r in chosen) + (Request("finish"),)
        return Action(inputs={"x_mm": self._pose[0], "y_mm": self._pose[1], "depth_mm": -5.0}, requests=requests)

    def _guess(self, scored: list[tuple[float, tuple[int, int]]]) -> list[tuple[int, int]]:
        """The cells reported when nothing stood out. ``random``: distinct cells drawn at random. ``best``: the
        cells whose evidence was strongest, not neighbouring each other (the max rule of a forced choice), and
        random cells only where no evidence at all was gathered (a person who noted nothing)."""
        cells = [(c, r) for r in range(1, self.rows + 1) for c in range(1, self.columns + 1)]
        n = min(self.params["guesses"], len(cells))
        chosen: list[tuple[int, int]] = []
        if self.params["guess"] == "best":
            for score, cell in scored:
                if len(chosen) == n or not math.isfinite(score):
                    break
                if all(max(abs(cell[0] - c[0]), abs(cell[1] - c[1])) > 1 for c in chosen):
                    chosen.append(cell)
            if len(chosen) == n:
                return chosen
            cells = [c for c in cells if c not in chosen]
        idx = self._rng.choice(len(cells), size=n - len(chosen), replace=False)
        return chosen + [cells[i] for i in sorted(idx)]


def _lerp(a, b, f):
    return tuple(x + (y - x) * f for x, y in zip(a, b, strict=True))


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
