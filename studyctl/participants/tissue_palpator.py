"""A virtual participant who palpates a stiffness-map tissue (seeds 002 and 003) through the simulated
device and the screen, and reports nodules from what it perceived.

What it may use: the visible tissue surface (``TrialInfo.public["surface"]`` or the view's ``surface``,
device frame), the cursor on screen (the view's ``cursor_mm`` in visual conditions), what its hand feels
(the device's delivered ``fx_n``/``fy_n``/``fz_n``) and where its hand is (the device's ``x_mm``/``y_mm``/
``z_mm``: proprioception). Never the scene's truth.

Strategy: a survey of presses along parallel lines (``line_spacing_mm`` apart, ``press_spacing_mm`` between
presses, every other line shifted by half a spacing, boustrophedon), then a 3 × 3 follow-up grid
(``follow_up_spacing_mm``) around each spot whose survey evidence exceeds ``follow_up_z`` (at most
``follow_up_count`` spots). A press brings the watched point — the cursor when one is visible, else the hand —
from ``hover_mm`` above the visible surface to ``press_depth_mm`` below it with a saturated proportional law
on its error (``gain_per_s``), so the cursor's lag (pseudo-haptics) and the rendered force pushing the hand
back (the device's spring-held hand) are compensated the way a person does, by moving the hand further; with
``press_adaptation`` the pressing gain is raised by how little the watched point has yielded per hand millimetre
over the trial's presses (visuomotor gain adaptation), so a press keeps its pace under a slowed cursor; with
``press_steer: felt`` a press whose push is felt is steered by the hand's travel since the push was first felt
(proprioception) instead of the cursor's; its indentation is still read off the cursor.
Moves in the air are planned straight-line hand motions.

Perception per press (noise multiplicative, drawn from the trial's rng):

* force cue (FF, PHF+FF): the largest force felt at the bottom over the indentation seen there, the way
  people judge stiffness (force per displacement; ``force_weber``, ``depth_weber``);
* sliding survey (``slide_survey``; PHF, PHF+FF with the controller's ``lateral_ratio: normal``): once a press
  shows the cursor lagging the hand, each remaining survey line is slid at depth and read every
  ``slide_window_mm`` of cursor travel (hand over cursor travel sideways; the push with force feedback), see
  :mod:`.tissue_slide`;
* cursor cue (PHF, PHF+FF): hand travel over cursor travel during the last ``ratio_window_mm`` of the
  cursor's descent into the tissue (summed over the ticks in which the cursor descends),
  ``q ≈ 1/R_n = (f_n + 1)/R₀``, read as a force ``R₀·q − 1`` with ``R₀`` taken from how the cursor follows the
  hand in the air (``visual_weber``).

A cue is used only if it is perceivable: the force cue if forces were felt at all, the cursor cue if the
cursor visibly lagged the hand (median ``R₀·q − 1`` above 0.05 N). Each press's contrast is its cue over the
median of the survey presses within ``baseline_radius_mm``, minus one; cues are fused by inverse-variance
weighting (the maximum-likelihood integration seed 003 cites), noise levels being robust SDs over the survey.
Evidence at a press averages the presses within half ``cluster_radius_mm``; spots above ``z_threshold`` SDs
are reported at their contrast-weighted centroid (at most ``max_reports``, or the nodule count when told),
one report per tick, then the participant finishes.

Re-palpation stops when a spot is decided: a Wald sequential probability ratio test per spot (nodule with the
contrast the survey suggested vs none, error rates ``follow_up_error``) over the re-palpation presses near it
is checked before each follow-up press, so a clear spot is settled by one or two presses and an ambiguous one
gets the whole 3 × 3 grid. The survey covers the visible surface unless the
person expects a number of nodules (``expect_spots``, from the practice run) and has felt that many clear spots, or,
with ``stop_yield``, expects the presses it has left to find fewer nodules than that (the unfelt ones may lie in the
part still unpressed or have been missed under the part pressed, ``stop_detect_belief``): it stops once it believes
it has found what there is to find (seed 003's time ran "until they thought they had found all the nodules").

Practice (``practice``: weights or learn; off by default): the engine runs seed 003's practice block before each
feedback condition's test (``info.public["practice"]``, its nodules shown as ``marks``); the person presses near each
mark and on plain tissue, learns per cue what a press near a nodule shows, and weights its press cues by that in the
condition's test (:mod:`.tissue_practice`). What it learnt is its memory, so a resumed session goes on with it.
With ``manual_practice: transparent`` (off by default) the engine also runs a manual condition's practice block
(seed 002's transparent phantom: the nodules are seen), palpated with the bare finger; what the person learns there
applies to that manual condition's test.

Tool tempo (``tool_tempo``, off by default at 1): in a trial whose device feedback does not say ``direct_touch`` the
hand holds a tool (seed 002's stylus), and the trial's tempo is multiplied by this person's factor, so how much a
stylus slows a person varies between people instead of being the same ratio for everyone.

Direct touch (manual conditions: the device's feedback says ``direct_touch``, the bare finger on the phantom):
the finger also feels the surface deformation over the pad, the cue that carries most of the information in
judging softness; it is fused with the force/displacement cue by inverse-variance weighting
(``cutaneous_ratio``), so one press's stiffness judgement is about three times finer than through a stylus.

Questionnaires: an item that compares combined feedback with force feedback alone (seed 003's end question)
is answered from the session's stored trial record that the engine passes with the item (``history``: each
completed trial's condition, its label, duration and number of reported spots), so a session resumed in a new
process answers as an uninterrupted one: whether its searches with both feedbacks named (force and
pseudo-haptic) found spots at a noticeably higher rate (spots + 1 per second, ``search_weber``) than those with
force feedback alone. Clearer cues make its sequential follow-up settle sooner and more spots pass its report
threshold, so the rate carries what it perceived. Only without a record (a bare trial loop) does it fall back on
its remembered percepts (cues perceived, evidence strength). Other items get the scale's middle code.

Parameters (``params=``): see :data:`PARAMS`.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.participants.tissue_cue_learning import CueReliability
from studyctl.participants.tissue_decision import SpotDecision
from studyctl.participants.tissue_hand import HandMotor
from studyctl.participants.tissue_params import PARAMS
from studyctl.participants.tissue_perception import AirRatios, PressPerception
from studyctl.participants.tissue_practice import practice_points
from studyctl.participants.tissue_questionnaire import Questionnaire
from studyctl.participants.tissue_slide import SlideSurvey
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo
from studyctl.plugins.params import Param, validate_params


def _surface_sampler(surface: Mapping[str, Any]):
    """The visible surface's bilinear ``height(x, y)`` (NaN off the tissue) and ``in_air(x, y, z)``, its bounds, where
    it is finite, and its grid."""
    xs = np.asarray(surface["xs_mm"], dtype=float)
    ys = np.asarray(surface["ys_mm"], dtype=float)
    h = np.asarray(surface["heights_mm"], dtype=float)
    if xs.ndim != 1 or ys.ndim != 1 or h.shape != (xs.size, ys.size) or xs.size < 2 or ys.size < 2:
        raise ModelParameterError("virtual_tissue_palpator: the visible surface must be xs_mm, ys_mm, heights_mm grids")
    x0, dx, y0, dy = float(xs[0]), float(xs[1] - xs[0]), float(ys[0]), float(ys[1] - ys[0])
    rows = h.tolist()
    nx, ny = xs.size, ys.size
    nx1, ny1, nx2, ny2 = nx - 1, ny - 1, nx - 2, ny - 2  # ints, as the bounds were computed per call

    def cell(x: float, y: float) -> tuple[int, int, float, float] | None:
        """The grid cell under (x, y) and where in it, or None off the grid."""
        u = (x - x0) / dx
        v = (y - y0) / dy
        if u < 0 or v < 0 or u > nx1 or v > ny1:
            return None
        i = int(u)
        if i > nx2:
            i = nx2
        j = int(v)
        if j > ny2:
            j = ny2
        return i, j, u - i, v - j

    def height(x: float, y: float) -> float:
        """Bilinear height of the visible surface; NaN off the tissue."""
        at = cell(x, y)
        if at is None:
            return math.nan
        i, j, tu, tv = at
        return (
            rows[i][j] * (1 - tu) * (1 - tv)
            + rows[i + 1][j] * tu * (1 - tv)
            + rows[i][j + 1] * (1 - tu) * tv
            + rows[i + 1][j + 1] * tu * tv
        )

    # The bilinear height is a weighted mean of its cell's corners, so it lies between the lowest and highest finite
    # height, give or take a few ulps of rounding (the slack is far wider). A cell whose corners are all finite (and
    # small enough that their weighted sum cannot overflow) has a finite height everywhere.
    usable = np.abs(h) < 1e300  # False for NaN and infinities
    lo, hi = (float(h[usable].min()), float(h[usable].max())) if usable.any() else (math.inf, -math.inf)
    slack = 1e-3 + 1e-9 * max(abs(lo), abs(hi)) if usable.any() else 0.0
    top = hi + 0.5 + slack
    floor = lo + 0.5 - slack
    on = (usable[:-1, :-1] & usable[1:, :-1] & usable[:-1, 1:] & usable[1:, 1:]).tolist()

    def in_air(x: float, y: float, z: float) -> bool:
        """``not isfinite(height(x, y)) or z > height(x, y) + 0.5``: the point off the tissue or more than half a
        millimetre above it. Above the highest surface point it is in the air, and at or below the lowest over a
        cell with a finite height it is not, without the height (most air and press ticks at seed 003, whose
        surface is flat); the height is looked up only in between."""
        if z > top:
            return True
        if z <= floor:
            at = cell(x, y)
            if at is None:
                return True
            if on[at[0]][at[1]]:
                return False
        above = height(x, y)
        return not math.isfinite(above) or z > above + 0.5

    return height, in_air, (float(xs[0]), float(xs[-1]), float(ys[0]), float(ys[-1])), np.isfinite(h), xs, ys


class VirtualTissuePalpator(HandMotor, PressPerception, SlideSurvey, SpotDecision, Questionnaire, Participant):
    """Presses a grid over the visible tissue, perceives force and cursor resistance, reports stiff spots."""

    name = "virtual_tissue_palpator"
    virtual = True
    PARAMS: ClassVar[tuple[Param, ...]] = PARAMS

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        super().__init__(params)
        self.params = validate_params("virtual_tissue_palpator participant", params, PARAMS)
        # what each trial felt like (its own percepts), for questionnaires at the end of a block or study
        self.experience: list[dict[str, Any]] = []
        # how reliable each slid cue has shown itself over this person's trials (slide_fusion: pooled)
        self._cue_learning = CueReliability(self.params["cue_prior_windows"], self.params["cue_excess"])
        # practice: weights|learn: the engine runs each feedback condition's practice block (nodules visible) for this
        # person; what it learnt there, per condition (tissue_practice), applies to that condition's test
        # thickness_prior: learn: the practice block also teaches how firm the tissue feels where it looks thin
        self._learns_rim = self.params["thickness_prior"] == "learn"
        self.practises = self.params["practice"] != "none" or self._learns_rim
        # manual_practice: transparent: the engine also runs a manual condition's practice block (seed 002's
        # transparent phantom, nodules seen) for this person, who palpates it with the bare finger
        self.practises_manual = self.params["manual_practice"] == "transparent"
        # press_steer: felt: once a push is felt, a press is steered by the hand's travel, not the cursor's
        self._steer_felt = self.params["press_steer"] == "felt"
        self.learnt: dict[str, dict[str, dict[str, float]]] = {}
        self.rim_learnt: dict[str, dict[str, dict[str, float]]] = {}  # per condition, per cue (tissue_rim)

    def memory(self) -> Mapping[str, Any]:
        """What carries over between trials: the cue tallies of slide_fusion: pooled and what each condition's
        practice taught (practice: weights|learn); nothing otherwise, so a session's stored record is as before for
        every other person."""
        out: dict[str, Any] = {}
        if self.params["slide_fusion"] == "pooled":
            out["slid_cues"] = self._cue_learning.to_json()
        if self.practises:
            out["practice"] = _learnt_copy(self.learnt)
        if self._learns_rim:
            out["thickness_prior"] = _learnt_copy(self.rim_learnt)
        return out

    def recall(self, memory: Mapping[str, Any]) -> None:
        cues = memory.get("slid_cues")
        if isinstance(cues, Mapping):
            self._cue_learning.load(cues)
        learnt = memory.get("practice")
        if isinstance(learnt, Mapping):
            self.learnt = _learnt_from(learnt)
        rim = memory.get("thickness_prior")
        if isinstance(rim, Mapping):
            self.rim_learnt = _learnt_from(rim)

    # ------------------------------------------------------------------ trial set-up
    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        self.info = info
        self.rng = rng
        # a practice block (its nodules shown as marks) for a person who learns from it; else a test trial
        learns = self.practises or self.practises_manual
        self._marks = list(info.public.get("marks") or ()) if learns and info.public.get("practice") else None
        self._ticks = 0
        self._t_prev = 0.0
        self._dt = 0.0
        self._height = None
        self._in_air = None  # (x, y, z) above or off the visible surface (_surface_sampler), once it is seen
        start = info.public.get("start_mm")
        self._hand = [float(v) for v in start] if start is not None else None
        self._presses: list[dict[str, float]] = []
        self._plan: list[tuple[float, float]] = []
        self._phase = "setup"
        self._phase_t = 0.0
        self._target = (0.0, 0.0, 0.0)
        self._goal: tuple[float, float, float] | None = None
        self._settle_at = math.inf
        self._replan = False
        self._press: dict[str, Any] = {}
        # Cursor and hand travel of each tick in the air, as flat float64 buffers: every follow-up decision takes
        # their median ratio, and converting a list of a few hundred thousand tuples each time was a second
        # per participant.
        self._air_dc = array("d")
        self._air_dh = array("d")
        self._air_ratios = AirRatios()  # their ratios, sorted as far as looked at (R₀, _r0)
        self._last_cursor: tuple[float, float, float] | None = None
        self._last_handle: tuple[float, float, float] | None = None
        self._reports: list[tuple[float, float]] = []
        self._spots: list[dict[str, Any]] = []
        self._follow_up: dict[str, Any] = {}
        self._direct = False
        self._stopped_early = False
        self._survey_total = 0
        # how far the watched point has gone into the tissue per millimetre the hand was told to press, as learnt
        # over this trial's presses (1: as in the air); the press is steered with the inverse as extra gain
        self._press_yield = 1.0
        self._bottom_pushes: list[float] = []  # the push felt at each press's bottom so far (press_force_stop)
        # a sliding survey (slide_survey, where the cursor slows): the line each start point slides to
        self._slide_mode = False
        self._slide_ends: dict[tuple[float, float], tuple[float, float]] = {}
        self._slide_points: list[tuple[float, float]] = []
        self._slide_checked = False
        self._slide_probe_lag = 0.0
        self._grip_held = 1.0  # the grip last given to the device (slide_grip)
        self.perceived: dict[str, Any] = {}
        self._slide_weights: dict[str, float] | None = None  # each slid cue's weight at the last look (diagnostics)
        self._motor = self._trial_motor(info, rng)
        # tool_tempo: whether the hand holds a tool is known from the device's first feedback (direct_touch or not)
        self._tool_checked = self.params["tool_tempo"] == 1.0
        # Options read at every tick that are off for most people: whether any of the optional press stops
        # (press_force_stop, press_stall_stop, press_hand_stop; each returns False when off) and slide_damping's grip
        # (None when 1) can act, so the tick skips their calls when none can.
        p = self.params
        self._extra_stops = p["press_force_stop"] > 0 or p["press_stall_stop"] > 0 or p["press_hand_stop"] > 0
        self._grips = p["slide_damping"] != 1.0

    def _trial_motor(self, info: TrialInfo, rng: np.random.Generator) -> dict[str, float]:
        """This trial's movement speeds: the person's tempo, grown with practice over the session's trials and
        varied from trial to trial (log-normal, mean 1, CV ``tempo_trial_cv``)."""
        p = self.params
        done = max(int(info.public.get("trial_index") or 1) - 1, 0)  # trials this person did before this one
        tempo = p["tempo"] * (1.0 + p["practice_gain"] * (1.0 - 0.5**done))
        cv = p["tempo_trial_cv"]
        if cv > 0:
            s2 = math.log1p(cv * cv)
            tempo *= math.exp(math.sqrt(s2) * float(rng.normal()) - s2 / 2.0)
        return {
            "tempo": tempo,
            "move": p["move_speed_mm_s"] * tempo,
            "press": p["press_speed_mm_s"] * tempo,
            "gain": p["gain_per_s"],  # the hand-eye loop's time constant is not a matter of tempo
            "settle": p["settle_s"] / tempo,
            "dwell": p["dwell_s"] / tempo,
        }

    def _setup(self, surface: Mapping[str, Any]) -> None:
        p = self.params
        self._height, self._in_air, (x0, x1, y0, y1), valid, xs, ys = _surface_sampler(surface)
        m = p["margin_mm"]
        plan = []
        ylines = np.arange(y0 + m, y1 - m + 1e-9, p["line_spacing_mm"])
        for k, y in enumerate(ylines):
            shift = 0.5 * p["press_spacing_mm"] if k % 2 else 0.0  # a staggered (triangular) lattice
            xline = np.arange(x0 + m + shift, x1 - m + 1e-9, p["press_spacing_mm"])
            if k % 2:
                xline = xline[::-1]
            for x in xline:
                # only where the visible tissue is, with the margin all round
                if all(
                    math.isfinite(self._height(float(x) + ox, float(y) + oy))
                    for ox, oy in ((0, 0), (m, 0), (-m, 0), (0, m), (0, -m))
                ):
                    plan.append((float(x), float(y)))
        if not plan:
            raise ModelParameterError(
                "virtual_tissue_palpator: no press point fits on the visible surface; lower margin_mm or the spacings"
            )
        self._stage = "survey"
        self._survey_total = len(plan)  # the survey lattice planned over the visible block (stop_yield's coverage)
        if self._marks is not None:
            if not self._marks:
                raise ModelParameterError("virtual_tissue_palpator: practice: weights|learn needs the practice block's "
                                          "visible nodules (the scene's marks in TrialInfo.public['marks'])")
            plan = practice_points(plan, self._marks, p["practice_presses"], p["press_spacing_mm"],
                                   p["cluster_radius_mm"], lambda x, y: math.isfinite(self._height(x, y)), self.rng)
            self._stage = "practice"  # not a survey: no sliding, no early stop, no re-palpation, no reports
        self._plan = plan[::-1]  # pop() from the end
        self._next_press()

    def _next_press(self) -> None:
        if self._stage == "survey" and self._plan and self._found_enough():
            self._plan = []
            self._stopped_early = True
        if not self._plan and self._stage == "practice":
            self._phase = "decide"
            return
        if not self._plan and self._stage == "survey":
            self._stage = "follow_up"
            # a slid survey is not re-palpated by presses: their cue is read another way (a descent, not a slide)
            self._spots = [] if self._slide_mode else self._follow_up_spots()
        if self._stage == "follow_up":
            self._plan = self._next_follow_up()
        if not self._plan:
            self._phase = "decide"
            return
        x, y = self._plan.pop()
        h = self._height(x, y)
        self._press = {"x": x, "y": y, "h": h}
        self._phase = "travel"
        self._phase_t = 0.0
        self._target = (x, y, h + self.params["hover_mm"])
        self._replan = True

    # ------------------------------------------------------------------ the tick
    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        dt = t - self._t_prev
        if 0.0 > dt:  # max(dt, 0.0) without the call: a clock that steps back gives no time
            dt = 0.0
        self._t_prev = t
        self._dt = dt
        self._ticks += 1
        view = percept.get("view")
        if type(view) is not dict and not isinstance(view, Mapping):  # a scene's view is a dict: skip the ABC check
            view = None
        if self._height is None:
            surface = (view or {}).get("surface") or self.info.public.get("surface")
            if surface:
                self._setup(surface)
            elif self._ticks > 3:
                raise ModelParameterError(
                    "virtual_tissue_palpator: the tissue surface is not visible; run the condition with visual: "
                    "realtime or pass the scene's public() surface in TrialInfo.public"
                )
        if "x_mm" in percept:
            handle = (float(percept["x_mm"]), float(percept["y_mm"]), float(percept["z_mm"]))
        else:
            handle = None
        if self._hand is None:
            self._hand = list(handle) if handle is not None else [0.0, 0.0, 100.0]
        if self._height is None:
            return Action(inputs=self._inputs())
        cursor = view.get("cursor_mm") if view is not None else None
        if cursor is not None:
            cursor = tuple(map(float, cursor))
        ctrl = cursor if cursor is not None else (handle if handle is not None else tuple(self._hand))
        if percept.get("direct_touch"):
            self._direct = True
        if not self._tool_checked and handle is not None:
            self._tool_checked = True
            if not self._direct:
                self._motor = _with_tempo(self._motor, self.params["tool_tempo"])
        force = 0.0
        if "fx_n" in percept:
            force = math.sqrt(percept["fx_n"] ** 2 + percept["fy_n"] ** 2 + percept["fz_n"] ** 2)
        steer = ctrl  # what the hand is steered by; ctrl stays what the person watches and judges depth by
        if self._steer_felt and cursor is not None and handle is not None and self._phase in ("press", "dwell"):
            steer = self._felt_depth(ctrl, handle, force)
        self._observe_air(cursor, handle, ctrl)
        self._phase_t += dt
        requests: tuple[Request, ...] = ()
        if self._phase == "decide":
            self._reports = self._decide()
            self._phase = "report"
        if self._phase == "report":
            if self._reports:
                x, y = self._reports.pop(0)
                requests = (Request("report", {"x_mm": x, "y_mm": y}),)
            else:
                self._phase = "done"
                requests = (Request("finish"),)
            return Action(inputs=self._inputs(), requests=requests)
        if self._phase == "done":
            return Action(inputs=self._inputs(), requests=(Request("finish"),))
        self._advance(ctrl, cursor, handle, force, steer)
        self._move_hand(steer, dt)
        h = self._hand
        grip = self._grip(force) if self._grips else None
        if grip is not None:
            return Action({"x_mm": h[0], "y_mm": h[1], "z_mm": h[2], "grip_damping": grip})
        # positional: a frozen dataclass built from keywords costs twice as much, once per tick
        return Action({"x_mm": h[0], "y_mm": h[1], "z_mm": h[2]})

    def _push_reached(self, cursor, force: float) -> bool:
        """``press_force_stop``: where a cursor shows the press and a push is felt, the felt push reaching its
        fraction of the median bottom push of this trial's earlier presses ends the press as the cursor reaching the
        wanted depth does (redundant signals, Miller 1982). Off (0) by default; nothing felt never ends a press."""
        stop = self.params["press_force_stop"]
        if stop <= 0 or cursor is None or force <= 0.02 or len(self._bottom_pushes) < 3:
            return False
        return force >= stop * float(np.median(self._bottom_pushes))

    def _cursor_stalled(self, press: dict[str, Any], cursor) -> bool:
        """``press_stall_stop``: with a cursor on screen, the press ends once the cursor, in the tissue, has gone down
        less than that fraction of the hand's commanded descent over the last ``press_stall_s`` (a visible stall:
        the pseudo-haptic slowing read as resistance) instead of being servoed through its last millimetre. The
        hand's command is the person's own (efference copy), so a hand held back by rendered force stalls the cursor
        too. Off (0) by default: no state is kept and no random number drawn."""
        frac = self.params["press_stall_stop"]
        if frac <= 0 or cursor is None:
            return False
        window = press.setdefault("stall", [])
        now = self._phase_t
        if cursor[2] > press["h"]:  # above the visible surface: descending in the air, nothing to read yet
            window.clear()
            return False
        window.append((now, cursor[2], self._hand[2]))
        span = self.params["press_stall_s"]
        while len(window) > 1 and window[1][0] <= now - span:
            window.pop(0)
        t0, c0, h0 = window[0]
        if now - t0 < span - 1e-9:
            return False
        told = h0 - self._hand[2]
        return told > 0 and c0 - cursor[2] < frac * told

    def _hand_travelled(self, press: dict[str, Any], cursor, handle, force: float) -> bool:
        """``press_hand_stop``: with a cursor on screen, the press ends once the hand, by its own position sense, has
        gone down that multiple of the wanted depth since the cursor entered the visible tissue: the person presses
        by the hand's travel (which pseudo-haptic slowing leaves alone) rather than servoing the slowed cursor to
        depth. With ``press_hand_stop_push_n`` it ends so only while a push of that much is felt: a hand held back
        by a rendered force leaves the cursor near depth, while with pseudo-haptics alone nothing holds the hand and
        the slowed cursor would be left short. Off (0) by default: no state is kept and no random number drawn."""
        gain = self.params["press_hand_stop"]
        if gain <= 0 or cursor is None or handle is None:
            return False
        if cursor[2] > press["h"]:  # the cursor is still above the visible surface: the press has not begun
            return False
        entry = press.setdefault("hand_in", handle[2])
        if force < self.params["press_hand_stop_push_n"]:  # no push felt: the cursor alone shows the depth
            return False
        return entry - handle[2] >= gain * (press["h"] - self._target[2])

    def _inputs(self) -> dict[str, float]:
        h = self._hand
        return {"x_mm": h[0], "y_mm": h[1], "z_mm": h[2]}

    def _observe_air(self, cursor, handle, ctrl) -> None:
        """Out of contact, how far the cursor moves per hand millimetre (the participant's sense of R₀)."""
        if cursor is not None and handle is not None and self._last_cursor is not None and self._in_air is not None:
            # the hand's travel first: a still hand (most press and dwell ticks) records nothing, so the surface
            # under the cursor need not be looked up (in_air is a pure function: the same pairs are kept)
            dh = math.dist(handle, self._last_handle)
            if dh > 1e-3 and self._in_air(cursor[0], cursor[1], cursor[2]):
                self._air_dc.append(math.dist(cursor, self._last_cursor))
                self._air_dh.append(dh)
        self._last_cursor = cursor
        self._last_handle = handle

    def _advance(self, ctrl, cursor, handle, force, steer) -> None:
        p = self.params
        press = self._press
        if self._replan:
            self._plan_move(ctrl)
            self._replan = False
        # Each condition is evaluated only in the phase that uses it: they read the state, never change it.
        phase = self._phase
        timed_out = self._phase_t >= p["phase_timeout_s"]
        if phase == "travel":
            reached = self._goal_reached()
            settled = reached and self._phase_t >= self._settle_at  # the settle time before it is set below
            if reached and self._settle_at == math.inf:
                self._settle_at = self._phase_t + self._motor["settle"]
            if settled or timed_out:
                depth = p["press_depth_mm"] + p["depth_noise_mm"] * float(self.rng.normal())
                self._target = (press["x"], press["y"], press["h"] - max(depth, 0.2))
                self._goal, self._settle_at = None, math.inf
                self._phase, self._phase_t = "press", 0.0
                press.update(track=[], last=None, f_sum=0.0, f_max=0.0, z_sum=0.0, x_sum=0.0, y_sum=0.0, n_held=0)
        elif phase == "press":
            if cursor is not None and handle is not None:
                last = press["last"]
                press["last"] = (cursor[2], handle[2])
                if last is not None and cursor[2] < last[0] and last[0] <= press["h"]:
                    # Hand and cursor travel summed over the ticks in which the cursor descends in contact, so
                    # the cue is read while pressing only. Pairing new depth minima instead counted the hand's
                    # travel over rebounds too: up at R₀, back down at R₀/(f+1), each loop adds hand travel that
                    # depends on the hand's wobble, not on the tissue, so q overshot 1/R_n (spring-held hand
                    # without force feedback: 1.59 over the background for 1.54 by its descending ticks).
                    track = press["track"]
                    c_sum, h_sum = track[-1] if track else (0.0, 0.0)
                    track.append((c_sum + last[0] - cursor[2], h_sum + last[1] - handle[2]))
            # The press ends when the watched point first reaches the wanted depth: a person presses to a depth
            # and holds, without servoing the last fraction of a millimetre (a spring-held hand pressing on
            # rendered forces would oscillate about it for the whole phase timeout).
            near = steer[2] <= self._target[2] + p["tolerance_mm"]
            if p["press_adaptation"] > 0 and "in_at" not in press and steer[2] <= press["h"]:
                press["in_at"] = (steer[2], self._hand[2])  # the steered point enters the tissue (adaptation only)
            if (near or timed_out or force >= p["max_press_force_n"]
                    or (self._extra_stops and (self._push_reached(cursor, force) or self._cursor_stalled(press, cursor)
                                               or self._hand_travelled(press, cursor, handle, force)))):
                self._adapt_press_gain(press, steer)
                if self._slide_start(press, ctrl):
                    return
                self._phase, self._phase_t = "dwell", 0.0
                press["bx"], press["by"], press["bz"] = ctrl[0], ctrl[1], ctrl[2]
                press["hold"] = self._hold_time(press, force)
                press["w_t"], press["w_c"], press["w_felt"], press["w_since"] = [], [], 0.0, None
                if force > 0.02:  # the push felt at this press's bottom (press_force_stop's reference)
                    self._bottom_pushes.append(force)
        elif phase == "dwell":
            # the force and indentation held at the bottom, averaged over the hold (judged from the terminal
            # force, Tan et al. 1995), so a transient of the hand's own dynamics does not count as stiffness
            if not self._steady(press, force):
                # the push still changes (the hand settling against the tissue): judge from when it is steady
                press["f_sum"] = press["f_max"] = press["x_sum"] = press["y_sum"] = press["z_sum"] = 0.0
                press["n_held"], press["steady_t"] = 0, self._phase_t
            press["f_sum"] += force
            if force > press["f_max"] or not press["n_held"]:
                # the strongest push, and how deep the tool was when it pushed that hard
                press["f_max"], press["z_at_max"] = force, ctrl[2]
            press["x_sum"] += ctrl[0]
            press["y_sum"] += ctrl[1]
            press["z_sum"] += ctrl[2]
            press["n_held"] += 1
            held = self._phase_t - press.get("steady_t", 0.0)
            if p["judge_from_bottom"]:
                # The push is felt, and evidence about it gathered, from the moment the press stops (Ratcliff &
                # McKoon 2008); waiting for it to be steady only decides which push is read. So the hold runs
                # from the bottom, and the press is released once it is also steady for the shortest dwell.
                done = self._phase_t >= press["hold"] and held >= self._motor["dwell"]
            else:
                done = held >= press["hold"]
            if done or self._phase_t >= press["hold"] + p["phase_timeout_s"]:
                self._record(press)
                self._slide_switch(press)
                self._target = (ctrl[0], ctrl[1], press["h"] + p["hover_mm"])
                self._phase, self._phase_t = "lift", 0.0
                self._replan = True
        elif phase == "slide":
            if self._slide_tick(press, ctrl, cursor, handle, force):
                self._slide_check(press["slide_from"])
                self._target = (ctrl[0], ctrl[1], press["h"] + p["hover_mm"])
                self._phase, self._phase_t = "lift", 0.0
                self._replan = True
        elif phase == "lift":
            if self._goal_reached() or timed_out:
                self._goal, self._settle_at = None, math.inf
                self._next_press()


def _with_tempo(motor: Mapping[str, float], factor: float) -> dict[str, float]:
    """The trial's motor speeds at ``factor`` times its tempo (tool_tempo: a stylus in the hand); the hand-eye gain
    is not a matter of tempo, as in ``_trial_motor``."""
    return {**motor, "tempo": motor["tempo"] * factor, "move": motor["move"] * factor,
            "press": motor["press"] * factor, "settle": motor["settle"] / factor, "dwell": motor["dwell"] / factor}


def _learnt_copy(learnt: Mapping[str, Mapping[str, Mapping[str, float]]]) -> dict[str, dict[str, dict[str, float]]]:
    """A copy of what practice taught, per condition and cue, for the session's memory (:func:`_learnt_from` reads
    it back)."""
    return {cond: {name: dict(c) for name, c in cues.items()} for cond, cues in learnt.items()}


def _learnt_from(stored: Mapping[str, Any]) -> dict[str, dict[str, dict[str, float]]]:
    """What a condition's practice taught, per cue, as stored in a session's memory (JSON)."""
    return {str(cond): {str(name): {k: float(v) for k, v in c.items()} for name, c in cues.items()}
            for cond, cues in stored.items()}
