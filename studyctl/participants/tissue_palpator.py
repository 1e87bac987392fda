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
back (the device's spring-held hand) are compensated the way a person does, by moving the hand further.
Moves in the air are planned straight-line hand motions.

Perception per press (noise multiplicative, drawn from the trial's rng):

* force cue (FF, PHF+FF): the largest force felt at the bottom over the indentation seen there, the way
  people judge stiffness (force per displacement; ``force_weber``, ``depth_weber``);
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
gets the whole 3 × 3 grid. The survey itself always covers the visible
surface: with the nodule count unknown nothing the participant felt can tell it that no nodule remains.

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
from bisect import bisect_right
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo
from studyctl.plugins.params import Param, validate_params

PARAMS = (
    # ---- search strategy (between-subject traits: how densely a person surveys)
    Param("line_spacing_mm", 8.0, low=1.0, high=50.0, unit="mm",
          source="CHOSEN: survey lines closer than a nodule's reach; spread between people is the systematic "
          "(dense) vs quick (sparse) survey (Saunders et al. 1986: coverage differed with the search pattern)"),
    Param("press_spacing_mm", 8.0, low=1.0, high=50.0, unit="mm",
          source="CHOSEN: every other line shifted by half this (a staggered lattice)"),
    Param("margin_mm", 6.0, low=0.0, high=50.0, unit="mm", source="CHOSEN: stay off the tissue's edge"),
    # ---- motor behaviour
    Param("press_depth_mm", 5.0, low=0.5, high=15.0, unit="mm", source="CHOSEN: inside the 2-7 mm maps"),
    Param("depth_noise_mm", 0.2, low=0.0, high=5.0, unit="mm", source="CHOSEN: press-to-press depth scatter"),
    Param("hover_mm", 2.0, low=0.5, high=30.0, unit="mm", source="CHOSEN: lift just clear of the surface"),
    Param("move_speed_mm_s", 60.0, low=1.0, high=500.0, unit="mm/s",
          source="CHOSEN: hand transport between presses, before tempo"),
    Param("press_speed_mm_s", 40.0, low=1.0, high=500.0, unit="mm/s",
          source="CHOSEN: indentation speed before tempo (seed 003 scanned at 30 mm/s)"),
    Param("gain_per_s", 8.0, low=0.5, high=200.0, unit="1/s",
          source="CHOSEN: 125 ms hand-eye time constant at tempo 1, stable with the device's spring-held hand (4 Hz)"),
    Param("tempo", 1.0, low=0.1, high=10.0,
          source="FITTED: a person's motor tempo (between-subject trait): multiplies the move and press speeds and "
          "divides the settle time and the shortest dwell"),
    Param("tempo_trial_cv", 0.0, low=0.0, high=1.0,
          source="CHOSEN: trial-to-trial (within-person) variation of the tempo, log-normal with this CV, drawn "
          "from the trial's stream"),
    Param("practice_gain", 0.0, low=0.0, high=2.0,
          source="CHOSEN: learning: the tempo grows by this fraction over a session's trials, half of it by the "
          "second trial (Adams et al.: most of the practice gain in lump detection came within 1-2 sessions)"),
    Param("hold_gain_ratio", 0.25, low=0.0, high=1.0,
          source="CHOSEN: while holding a press the depth is corrected this much more slowly than while pressing "
          "(a 4/s loop at tempo 2 stays clear of the 4-5 Hz resonance of a spring-held hand on the tissue)"),
    Param("tolerance_mm", 0.3, low=0.01, high=5.0, unit="mm", source="CHOSEN: depth accuracy at the press bottom"),
    Param("settle_s", 0.05, low=0.0, high=5.0, unit="s", source="CHOSEN: a pause before pressing, at tempo 1"),
    Param("phase_timeout_s", 1.5, low=0.1, high=30.0, unit="s", source="CHOSEN: a stuck movement is abandoned"),
    Param("dwell_s", 0.08, low=0.0, high=5.0, unit="s",
          source="CHOSEN: the shortest hold at a press bottom (a clear cue is judged at once), at tempo 1"),
    # ---- perception (Weber fractions are the SD of one judgement made over judge_time_s)
    Param("force_weber", 0.06, low=0.0, high=1.0,
          source="CITED: force JND 7 % (Pang, Tan & Durlach 1991) to 10 % on a force-feedback device (Allin et "
          "al. 2002); σ of one judgement = JND/(√2·0.954) at 75 % correct, 8 % → 0.06"),
    Param("depth_weber", 0.05, low=0.0, high=1.0,
          source="CHOSEN: reading the indentation depth (seen on screen, or felt by the hand's position)"),
    Param("visual_weber", 0.074, low=0.0, high=1.0,
          source="CITED: visual speed Weber fraction ≈ 7 % at 4-64 deg/s (Vision Res 1988;28:1323), varying "
          "considerably between people (J Vis 2018;18(6):15); 10 % JND → σ 0.074"),
    Param("hand_weber", 0.0, low=0.0, high=1.0,
          source="CHOSEN: the hand's own travel, judged by proprioception, against which the cursor's slowing is "
          "seen (the cursor cue compares the two; 0: the hand's travel is known exactly)"),
    Param("judge_time_s", 0.3, low=0.01, high=10.0, unit="s",
          source="CHOSEN: the hold over which one judgement has the Weber fractions above; a longer hold averages "
          "the sensory noise down as 1/√time (evidence accumulation, Ratcliff & McKoon 2008)"),
    Param("press_precision", 0.0, low=0.0, high=1.0,
          source="FITTED: decision criterion per press: the person holds a press until its stiffness judgement "
          "(all cues fused) has this SD or less, at most max_dwell_s (0: always the shortest dwell)"),
    Param("steady_rate_n_s", 2.0, low=0.01, high=100.0, unit="N/s",
          source="CHOSEN: a push whose average changes faster than this is felt as still settling (0.1 N in 50 ms, "
          "about a force JND at 1 N); the judgement starts once it is steady"),
    Param("steady_window_s", 0.2, low=0.01, high=2.0, unit="s",
          source="CHOSEN: steadiness is judged by comparing the push averaged over the last half of this window "
          "with the half before; 0.1 s halves span three cycles of the ~30 Hz on/off push that seed 003's "
          "release-on-retract rendering gives a held stylus, and people cannot modulate a force faster than "
          "5-10 Hz (Brooks 1990, telerobotic response requirements), so a judgement of 'steady' takes this long"),
    Param("max_dwell_s", 2.0, low=0.0, high=30.0, unit="s", source="CHOSEN: nobody holds one press longer"),
    Param("force_trust", 1.0, low=0.0, high=1.0,
          source="CHOSEN: the share of the force cue's information a person uses (1: statistically optimal "
          "fusion, Ernst & Banks 2002)"),
    Param("cursor_trust", 1.0, low=0.0, high=1.0,
          source="FITTED: the share of the cursor cue's information a person uses: a visual-only stiffness cue "
          "is believed less than a felt one (the pseudo-haptic illusion weakens with exposure, Front VR 2024)"),
    Param("ratio_window_mm", 2.0, low=0.2, high=20.0, unit="mm",
          source="CHOSEN: the cursor's slowing is judged over the last part of its travel"),
    Param("max_press_force_n", 3.0, low=0.1, high=20.0, unit="N", source="CHOSEN: below the Omni's 3.3 N"),
    # ---- decision
    Param("baseline_radius_mm", 25.0, low=2.0, high=200.0, unit="mm",
          source="CHOSEN: a spot is compared with the tissue around it"),
    Param("cluster_radius_mm", 10.0, low=1.0, high=100.0, unit="mm", source="CHOSEN: a nodule's reach"),
    Param("z_threshold", 3.0, low=0.5, high=50.0,
          source="FITTED: confidence to report: a spot's averaged contrast in SDs of the press noise"),
    Param("report_fraction", 0.0, low=0.0, high=1.0,
          source="FITTED: a spot is reported only if it feels at least this fraction as stiff (contrast) as the "
          "clearest one: what a nodule feels like is known from the practice run with visible nodules"),
    Param("expect_spots", 0, low=0, high=20, kind=int,
          source="CHOSEN: how many nodules a person expects (seen in the practice run with visible nodules); a "
          "targeted searcher stops surveying once it has felt that many clear spots (0: it surveys everything)"),
    Param("stop_z", 8.0, low=1.0, high=1000.0,
          source="FITTED: how clear (SDs of the press noise) each expected spot must feel before the survey stops; "
          "very high for a systematic searcher who covers the whole surface anyway"),
    Param("stop_min_presses", 10, low=5, high=500, kind=int,
          source="CHOSEN: survey presses a targeted searcher makes before it may end its survey: it first learns what "
          "the tissue around feels like (the noise its spots stand out of is estimated from these presses)"),
    Param("follow_up_z", 1.5, low=0.0, high=50.0,
          source="CHOSEN: survey presses this suspicious are re-palpated"),
    Param("follow_up_shrink", 0.5, low=0.05, high=1.0,
          source="CHOSEN: the nodule contrast a re-palpated spot is tested for, as a share of its survey contrast "
          "(the most suspicious survey presses overstate it)"),
    Param("follow_up_min", 2, low=1, high=9, kind=int,
          source="CHOSEN: presses a person makes at a suspicious spot before dismissing it"),
    Param("follow_up_count", 5, low=0, high=50, kind=int, source="CHOSEN: spots re-palpated at most"),
    Param("follow_up_spacing_mm", 4.0, low=0.5, high=20.0, unit="mm", source="CHOSEN: a 3 × 3 local grid"),
    Param("max_reports", 6, low=1, high=100, kind=int, source="CHOSEN: nobody marks more spots"),
    Param("follow_up_error", 0.05, low=1e-4, high=0.5,
          source="CHOSEN: confidence to settle a re-palpated spot: Wald's SPRT error rates (α = β)"),
    Param("cutaneous_ratio", 0.354, low=0.01, high=10.0,
          source="CITED: Bergmann Tiest & Kappers 2009 (IEEE ToH 2:189): compliance Weber fraction 15 % by direct "
          "touch, more than trebled without the finger's surface-deformation cue; optimal cue combination then "
          "gives the skin cue σ = 1/√8 of the force/displacement cue's"),
    Param("search_weber", 0.15, low=0.01, high=1.0,
          source="CHOSEN: a search rate (spots found per time) this much higher is noticed; judgements of how "
          "long a minutes-long search took are coarser than the 8-10 % of force and speed"),
)


def _surface_sampler(surface: Mapping[str, Any]):
    xs = np.asarray(surface["xs_mm"], dtype=float)
    ys = np.asarray(surface["ys_mm"], dtype=float)
    h = np.asarray(surface["heights_mm"], dtype=float)
    if xs.ndim != 1 or ys.ndim != 1 or h.shape != (xs.size, ys.size) or xs.size < 2 or ys.size < 2:
        raise ModelParameterError("virtual_tissue_palpator: the visible surface must be xs_mm, ys_mm, heights_mm grids")
    x0, dx, y0, dy = float(xs[0]), float(xs[1] - xs[0]), float(ys[0]), float(ys[1] - ys[0])
    rows = h.tolist()
    nx, ny = xs.size, ys.size
    nx1, ny1, nx2, ny2 = nx - 1, ny - 1, nx - 2, ny - 2  # ints, as the bounds were computed per call

    def height(x: float, y: float) -> float:
        """Bilinear height of the visible surface; NaN off the tissue."""
        u = (x - x0) / dx
        v = (y - y0) / dy
        if u < 0 or v < 0 or u > nx1 or v > ny1:
            return math.nan
        i = int(u)
        if i > nx2:
            i = nx2
        j = int(v)
        if j > ny2:
            j = ny2
        tu, tv = u - i, v - j
        return (
            rows[i][j] * (1 - tu) * (1 - tv)
            + rows[i + 1][j] * tu * (1 - tv)
            + rows[i][j + 1] * (1 - tu) * tv
            + rows[i + 1][j + 1] * tu * tv
        )

    return height, (float(xs[0]), float(xs[-1]), float(ys[0]), float(ys[-1])), np.isfinite(h), xs, ys


class VirtualTissuePalpator(Participant):
    """Presses a grid over the visible tissue, perceives force and cursor resistance, reports stiff spots."""

    name = "virtual_tissue_palpator"
    virtual = True
    PARAMS: ClassVar[tuple[Param, ...]] = PARAMS

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        super().__init__(params)
        self.params = validate_params("virtual_tissue_palpator participant", params, PARAMS)
        # what each trial felt like (its own percepts), for questionnaires at the end of a block or study
        self.experience: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ trial set-up
    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        self.info = info
        self.rng = rng
        self._ticks = 0
        self._t_prev = 0.0
        self._dt = 0.0
        self._height = None
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
        self._last_cursor: tuple[float, float, float] | None = None
        self._last_handle: tuple[float, float, float] | None = None
        self._reports: list[tuple[float, float]] = []
        self._spots: list[dict[str, Any]] = []
        self._follow_up: dict[str, Any] = {}
        self._direct = False
        self._stopped_early = False
        self.perceived: dict[str, Any] = {}
        self._motor = self._trial_motor(info, rng)

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
        self._height, (x0, x1, y0, y1), valid, xs, ys = _surface_sampler(surface)
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
        self._plan = plan[::-1]  # pop() from the end
        self._stage = "survey"
        self._next_press()

    def _found_enough(self) -> bool:
        """A targeted searcher ends its survey once it has felt as many clear spots as it expects nodules (known
        from the practice run): ``expect_spots`` spots each above ``stop_z`` SDs. Checked every third press."""
        p = self.params
        if p["expect_spots"] <= 0 or len(self._presses) < p["stop_min_presses"] or len(self._presses) % 3:
            return False
        ev = self._evidence()
        if ev is None:
            return False
        spots = self._clusters(*ev, threshold=p["stop_z"], limit=p["expect_spots"])
        return len(spots) >= p["expect_spots"]

    def _next_press(self) -> None:
        if self._stage == "survey" and self._plan and self._found_enough():
            self._plan = []
            self._stopped_early = True
        if not self._plan and self._stage == "survey":
            self._stage = "follow_up"
            self._spots = self._follow_up_spots()
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
        dt = max(t - self._t_prev, 0.0)
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
        force = 0.0
        if "fx_n" in percept:
            force = math.sqrt(percept["fx_n"] ** 2 + percept["fy_n"] ** 2 + percept["fz_n"] ** 2)
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
        self._advance(ctrl, cursor, handle, force)
        self._move_hand(ctrl, dt)
        h = self._hand
        # positional: a frozen dataclass built from keywords costs twice as much, once per tick
        return Action({"x_mm": h[0], "y_mm": h[1], "z_mm": h[2]})

    def _inputs(self) -> dict[str, float]:
        h = self._hand
        return {"x_mm": h[0], "y_mm": h[1], "z_mm": h[2]}

    def _move_hand(self, ctrl: tuple[float, float, float], dt: float) -> None:
        """Moves in the air are planned (open loop, straight, at ``move_speed_mm_s``); presses are steered by
        a saturated proportional law on what the participant watches (cursor or hand)."""
        m = self._motor
        h = self._hand
        if self._goal is not None:
            gx, gy, gz = self._goal
            ex, ey, ez = gx - h[0], gy - h[1], gz - h[2]
            dist = math.sqrt(ex * ex + ey * ey + ez * ez)
            step = m["move"] * dt
            k = 1.0 if dist <= step else step / dist
            h[0] += k * ex
            h[1] += k * ey
            h[2] += k * ez
            return
        tx, ty, tz = self._target
        ex, ey, ez = tx - ctrl[0], ty - ctrl[1], tz - ctrl[2]
        k = m["gain"] * dt
        # holding a press: slow depth corrections only, well below the hand's own resonance against the tissue
        kz = k * self.params["hold_gain_ratio"] if self._phase == "dwell" else k
        vx, vy, vz = ex * k, ey * k, ez * kz
        lateral = m["move"] * dt
        vertical = m["press"] * dt
        lat = math.hypot(vx, vy)
        if lat > lateral:
            vx, vy = vx * lateral / lat, vy * lateral / lat
        vz = max(-vertical, min(vertical, vz))
        h[0] += vx
        h[1] += vy
        h[2] += vz

    def _plan_move(self, ctrl: tuple[float, float, float]) -> None:
        """Hand goal that brings the watched point to the target, never lower than the target height (a
        force pushing the hand back in the tissue vanishes in the air)."""
        t, h = self._target, self._hand
        self._goal = (h[0] + t[0] - ctrl[0], h[1] + t[1] - ctrl[1], max(h[2] + t[2] - ctrl[2], t[2]))

    def _goal_reached(self) -> bool:
        return self._goal is not None and math.dist(self._goal, self._hand) < 1e-9

    def _observe_air(self, cursor, handle, ctrl) -> None:
        """Out of contact, how far the cursor moves per hand millimetre (the participant's sense of R₀)."""
        if cursor is not None and handle is not None and self._last_cursor is not None and self._height is not None:
            h = self._height(cursor[0], cursor[1])
            if not math.isfinite(h) or cursor[2] > h + 0.5:
                dc = math.dist(cursor, self._last_cursor)
                dh = math.dist(handle, self._last_handle)
                if dh > 1e-3:
                    self._air_dc.append(dc)
                    self._air_dh.append(dh)
        self._last_cursor = cursor
        self._last_handle = handle

    def _advance(self, ctrl, cursor, handle, force) -> None:
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
            near = ctrl[2] <= self._target[2] + p["tolerance_mm"]
            if near or timed_out or force >= p["max_press_force_n"]:
                self._phase, self._phase_t = "dwell", 0.0
                press["bx"], press["by"], press["bz"] = ctrl[0], ctrl[1], ctrl[2]
                press["hold"] = self._hold_time(press, force)
                press["w_t"], press["w_c"], press["w_felt"], press["w_since"] = [], [], 0.0, None
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
            if held >= press["hold"] or self._phase_t >= press["hold"] + p["phase_timeout_s"]:
                self._record(press)
                self._target = (ctrl[0], ctrl[1], press["h"] + p["hover_mm"])
                self._phase, self._phase_t = "lift", 0.0
                self._replan = True
        elif phase == "lift":
            if self._goal_reached() or timed_out:
                self._goal, self._settle_at = None, math.inf
                self._next_press()

    def _steady(self, press: dict[str, Any], force: float) -> bool:
        """Whether the push felt at the press bottom has stopped changing: its average over the last half of
        ``steady_window_s`` (of the hold so far, when shorter) differs from its average over the half before by at
        most ``steady_rate_n_s`` times the half window, and has for a half window. A criterion over time, so it
        does not depend on the loop rate: seed 003's FF renders no normal force while the tool retracts, so a
        held stylus gets an on/off push of ~30 Hz (the spring-held hand chatters against the rule) and a
        tick-to-tick test never found it steady. No push felt at all is steady at once (nothing to wait for)."""
        ts, cs = press["w_t"], press["w_c"]
        t = self._phase_t
        ts.append(t)
        cs.append((cs[-1] if cs else 0.0) + force)
        if press["w_felt"] < force:
            press["w_felt"] = force
        if press["w_felt"] <= 0.02:
            return True
        # the window is what has been felt so far, up to steady_window_s: a push that stays put is steady at
        # once (a finger stopped on the tissue), one that changes is judged over the whole window
        half = 0.5 * min(self.params["steady_window_s"], t)
        n = len(ts)
        i1 = bisect_right(ts, t - half)
        i0 = bisect_right(ts, t - 2.0 * half)
        if i1 <= i0 or n <= i1:
            press["w_since"] = None
            return False
        # cumulative sums: the mean over ticks (i0, i1] and (i1, n-1]
        c0 = cs[i0 - 1] if i0 > 0 else 0.0
        early = (cs[i1 - 1] - c0) / (i1 - i0)
        late = (cs[-1] - cs[i1 - 1]) / (n - i1)
        if abs(late - early) > self.params["steady_rate_n_s"] * half:
            press["w_since"] = None
            return False
        # ... and has stayed so for a half window: a push that rises and falls again passes through equal
        # averages for a tick or two
        if press["w_since"] is None:
            press["w_since"] = t
        return t - press["w_since"] >= half

    def _cue_sigmas(self) -> tuple[float, float]:
        """SD of one judgement (over ``judge_time_s``) of the force cue (with the finger's skin cue when touching
        directly) and of the cursor cue."""
        p = self.params
        kin = math.hypot(p["force_weber"], p["depth_weber"])
        if self._direct:
            cut = p["cutaneous_ratio"] * kin
            kin = 1.0 / math.sqrt(1.0 / max(kin, 1e-9) ** 2 + 1.0 / max(cut, 1e-9) ** 2)
        return kin, math.hypot(p["visual_weber"], p["hand_weber"])

    def _r0(self) -> float:
        """How far the cursor moves per hand millimetre in the air (1 before any move was seen)."""
        if not self._air_dc:
            return 1.0
        return float(np.median(np.frombuffer(self._air_dc) / np.frombuffer(self._air_dh)))

    def _hold_time(self, press: dict[str, Any], force: float) -> float:
        """How long the person holds this press: until its stiffness judgement, fused over the cues this press
        gives (a force felt, a cursor seen to lag the hand), reaches ``press_precision`` (evidence accumulating
        as 1/√time), between the shortest dwell and ``max_dwell_s``. What it perceives, not what is true: the
        cues present are read off this press's own force and cursor travel."""
        p = self.params
        shortest = self._motor["dwell"]
        if p["press_precision"] <= 0:
            return shortest
        s_force, s_cursor = self._cue_sigmas()
        if force <= 0.02:
            # nothing is felt: holding still gathers no evidence (the cursor cue was read on the way down)
            return shortest
        # The cursor cue, seen during the descent, is already in hand when the hold starts; the felt force
        # accumulates information over the hold (1/σ² growing with time). Fused by reliability (Ernst & Banks
        # 2002), the hold needed shrinks by what the cursor already told.
        have = 0.0
        track = press.get("track") or []
        q = self._r0() * track[-1][1] / track[-1][0] if track and track[-1][0] > 0.5 else 1.0
        if q > 1.05:
            # The cursor cue's noise is on the slowing q = (f + 1)/R₀, the force's on f itself: as a judgement of
            # the force (R₀·q − 1) the cursor cue's relative SD is q/(q − 1) times its own (about 3× at q = 1.5).
            # Counting it at its own SD made a person with both cues release its presses early, and its force
            # judgements worse than with force feedback alone.
            have = p["cursor_trust"] / max(s_cursor * q / (q - 1.0), 1e-9) ** 2
        rate = p["force_trust"] / max(s_force, 1e-9) ** 2 / p["judge_time_s"]  # information per second held
        if rate <= 0:
            return shortest
        need = (1.0 / p["press_precision"] ** 2 - have) / rate
        return min(max(need, shortest), max(p["max_dwell_s"], shortest))

    def _record(self, press: dict[str, Any]) -> None:
        p = self.params
        rng = self.rng
        # a hold longer than one judgement's time averages the sensory noise down
        scale = math.sqrt(p["judge_time_s"] / max(press.get("hold", 0.0), p["judge_time_s"]))
        n = press.get("n_held", 0)
        # where the press was held (the cursor or the hand, as the participant sees or feels it)
        x, y = (press["x_sum"] / n, press["y_sum"] / n) if n else (press["bx"], press["by"])
        row = {"x": x, "y": y, "force": math.nan, "ratio": math.nan, "stage": self._stage}
        # The resistance felt is the strongest steady push of the hold: where the rendering drops the force
        # whenever the tool backs off (seed 003's FF), the mean would count those gaps as softness. It is judged
        # with the indentation (seen on the cursor or felt by the hand) at the moment it pushed that hard: over
        # a one-second hold the hand drifts deeper, and the strongest push paired with the mean depth read 2 %
        # press-to-press scatter (SD) out of uniform tissue (noise-free percepts, 1 s holds), paired at the push 0.4 %.
        held = press["f_max"] if n else 0.0
        depth = press["h"] - (press["z_at_max"] if n else press["bz"])
        if held > 0.0 and depth > 0.2:
            # Stiffness as people judge it: the force felt per indentation seen (Srinivasan & LaMotte 1995).
            felt = held * (1.0 + scale * p["force_weber"] * float(rng.normal()))
            seen = depth * (1.0 + scale * p["depth_weber"] * float(rng.normal()))
            row["force"] = felt / seen
            if self._direct:
                # The finger pad's surface-deformation cue judges the same stiffness with its own noise;
                # the two are fused by inverse-variance weighting (Ernst & Banks 2002).
                kin = math.hypot(p["force_weber"], p["depth_weber"])
                cut = p["cutaneous_ratio"] * kin
                skin = held / depth * (1.0 + scale * cut * float(rng.normal()))
                w_kin, w_cut = 1.0 / max(kin, 1e-9) ** 2, 1.0 / max(cut, 1e-9) ** 2
                row["force"] = (w_kin * row["force"] + w_cut * skin) / (w_kin + w_cut)
            # the judged push and the depth it was judged at, for comparing presses held at like depths
            row["felt"], row["seen"] = row["force"] * seen, seen
        track = press["track"]  # cumulative (cursor descent, hand descent) over the descending ticks
        if len(track) >= 2 and track[-1][0] > 0.5:
            bc, bh = track[-1]
            # the last ratio_window_mm of the cursor's descent (or all of it when it was shorter)
            k = next((i for i in range(len(track) - 1, -1, -1) if bc - track[i][0] >= p["ratio_window_mm"]), -1)
            oc, oh = track[k] if k >= 0 else (0.0, 0.0)
            if bc - oc > 0.2:
                # The cursor's travel is seen (visual speed) against the hand's, felt (proprioception), while the
                # cursor descends: the cue is watched for the window's descending ticks only (it is still during
                # the hold, so holding longer does not sharpen it; a slower descent does).
                watched = (len(track) - 1 - k if k >= 0 else len(track)) * self._dt
                seen_scale = math.sqrt(p["judge_time_s"] / max(watched, p["judge_time_s"]))
                noise = seen_scale * math.hypot(p["visual_weber"], p["hand_weber"])
                row["ratio"] = (bh - oh) / (bc - oc) * (1.0 + noise * float(rng.normal()))
                # how deep the cursor was over the window (its descent into the tissue, as seen on screen)
                row["ratio_seen"] = 0.5 * (bc + oc) * (1.0 + p["depth_weber"] * float(rng.normal()))
        self._presses.append(row)

    # ------------------------------------------------------------------ the decision
    def _evidence(self, follow_up: bool = False) -> tuple[np.ndarray, ...] | None:
        """Per press: position, combined stiffness contrast and its noise (inverse-variance cue fusion).

        Baselines (local medians) and noise levels (robust SDs) come from the survey presses only, so that
        the follow-up presses around a suspicious spot do not raise their own baseline. With ``follow_up`` a
        fourth array says which of the returned presses are re-palpation presses.
        """
        p = self.params
        rows = self._presses
        if len(rows) < 5:
            return None
        pts = np.array([[r["x"], r["y"]] for r in rows])
        survey = np.array([r["stage"] == "survey" for r in rows])
        cues: list[tuple[np.ndarray, str]] = []
        force = np.array([r["force"] for r in rows])
        if np.isfinite(force[survey]).sum() >= 5 and np.nanmedian(force[survey]) > 0.02:
            felt = np.array([r.get("felt", math.nan) for r in rows])
            seen = np.array([r.get("seen", math.nan) for r in rows])
            cues.append((_depth_matched(felt, seen, survey), "force"))
        ratio = np.array([r["ratio"] for r in rows])
        if np.isfinite(ratio[survey]).sum() >= 5:
            visual_force = self._r0() * ratio - 1.0
            if np.nanmedian(visual_force[survey]) > 0.05:  # the cursor visibly lags the hand: pseudo-haptics is on
                # the slowing grows with depth as the force does: compared at like depths, as the push is
                seen = np.array([r.get("ratio_seen", math.nan) for r in rows])
                cues.append((_depth_matched(visual_force, seen, survey), "cursor"))
        self.perceived = {"cues": [name for _, name in cues], "presses": len(rows), "survey": int(survey.sum()),
                          "survey_stopped_early": self._stopped_early}
        if not cues:
            return None
        d2 = ((pts[:, None, :] - pts[None, survey, :]) ** 2).sum(axis=2)
        near = d2 <= p["baseline_radius_mm"] ** 2
        num = np.zeros(len(pts))
        den = np.zeros(len(pts))
        trust = {"force": p["force_trust"], "cursor": p["cursor_trust"]}
        for values, name in cues:
            sv = values[survey]
            base = np.array([np.nanmedian(np.where(near[i], sv, np.nan)) for i in range(len(pts))])
            contrast = values / base - 1.0
            ok = np.isfinite(contrast)
            cs = contrast[survey & ok]
            if cs.size < 5:
                continue
            sigma = max(1.4826 * float(np.median(np.abs(cs - np.median(cs)))), 1e-3)
            w = trust[name] / sigma**2  # a cue believed less weighs less, and its evidence counts less
            if w <= 0:
                continue
            num += np.where(ok, contrast * w, 0.0)
            den += np.where(ok, w, 0.0)
        keep = den > 0
        if keep.sum() < 5:
            return None
        if follow_up:
            return pts[keep], num[keep] / den[keep], 1.0 / np.sqrt(den[keep]), ~survey[keep]
        return pts[keep], num[keep] / den[keep], 1.0 / np.sqrt(den[keep])

    def _clusters(self, pts: np.ndarray, contrast: np.ndarray, sigma: np.ndarray, threshold: float, limit: int):
        """Spots whose averaged contrast (presses within half a cluster radius) exceeds ``threshold`` SDs."""
        p = self.params
        rc = p["cluster_radius_mm"]
        d2 = ((pts[:, None, :] - pts[None, :, :]) ** 2).sum(axis=2)
        local = d2 <= (rc / 2.0) ** 2
        w = 1.0 / sigma**2
        mean = (local * (w * contrast)[None, :]).sum(axis=1) / (local * w[None, :]).sum(axis=1)
        z = mean * np.sqrt((local * w[None, :]).sum(axis=1))
        self.perceived["z_max"] = float(np.max(z)) if z.size else math.nan
        out: list[tuple[float, float, float, float]] = []  # x, y, z, the stiffest press's contrast
        taken = np.zeros(len(pts), dtype=bool)
        for i in np.argsort(-z):
            if len(out) >= limit or z[i] < threshold:
                break
            if taken[i]:
                continue
            members = d2[i] <= rc * rc
            # where it felt stiffest: the presses at least half as stiff as the stiffest one near this spot
            # (all positive contrasts pulled the spot towards the survey grid around a nodule)
            peak = float(np.max(np.where(members, contrast, -np.inf)))
            members &= (contrast > 0) & (contrast >= 0.5 * peak)
            weights = np.where(members, contrast * w, 0.0)
            if weights.sum() <= 0:
                continue
            cx, cy = (weights[:, None] * pts).sum(axis=0) / weights.sum()
            out.append((float(cx), float(cy), float(z[i]), peak))
            taken |= d2[i] <= 4.0 * rc * rc
        return out

    def _follow_up_spots(self) -> list[dict[str, Any]]:
        """Suspicious spots of the survey, each with its 3 × 3 re-palpation grid (centre first) and the contrast
        the survey suggested there (the alternative of the spot's sequential test)."""
        p = self.params
        ev = self._evidence()
        if ev is None or p["follow_up_count"] == 0:
            return []
        pts, contrast, sigma = ev
        spots = self._clusters(pts, contrast, sigma, threshold=p["follow_up_z"], limit=p["follow_up_count"])
        s = p["follow_up_spacing_mm"]
        out = []
        half = p["cluster_radius_mm"] / 2.0
        for cx, cy, _z, _mean in spots:
            grid = [(cx + ox, cy + oy) for ox in (0.0, -s, s) for oy in (0.0, -s, s)]
            near = ((pts - (cx, cy)) ** 2).sum(axis=1) <= half * half
            w = 1.0 / sigma[near] ** 2
            mu = float((w * contrast[near]).sum() / w.sum()) if near.any() else 0.0
            todo = [g for g in grid if math.isfinite(self._height(*g))]
            # the spot was picked for being the most suspicious: its survey contrast overstates what re-palpation
            # will feel (regression to the mean), so the alternative is shrunk
            mu *= p["follow_up_shrink"]
            out.append({"x": cx, "y": cy, "mu": max(mu, 1e-3), "todo": todo, "presses": 0})
        self._follow_up = {"follow_up_spots": [(sp["x"], sp["y"]) for sp in out], "follow_up_decisions": []}
        return out

    def _spot_llr(self, spot: dict[str, Any]) -> float:
        """Log-likelihood ratio, nodule (mean contrast ``mu``, what the survey suggested) against none (0), of the
        re-palpation presses within half a cluster radius of the spot (Gaussian contrasts with each press's own
        noise). Only presses made after the survey count: the survey's own presses chose ``mu``."""
        ev = self._evidence(follow_up=True)
        if ev is None:
            return 0.0
        pts, contrast, sigma, fresh = ev
        half = self.params["cluster_radius_mm"] / 2.0
        near = fresh & (((pts - (spot["x"], spot["y"])) ** 2).sum(axis=1) <= half * half)
        mu = spot["mu"]
        return float((mu * (contrast[near] - mu / 2.0) / sigma[near] ** 2).sum())

    def _next_follow_up(self) -> list[tuple[float, float]]:
        """The next re-palpation press: of the first spot still undecided by its sequential test, else none."""
        a = self.params["follow_up_error"]
        bound = math.log((1.0 - a) / a)  # Wald's bounds with α = β
        while self._spots:
            spot = self._spots[0]
            llr = self._spot_llr(spot)
            undecided = -bound < llr < bound or (llr <= -bound and spot["presses"] < self.params["follow_up_min"])
            if spot["todo"] and undecided:
                spot["presses"] += 1
                return [spot["todo"].pop(0)]
            verdict = "nodule" if llr >= bound else ("none" if llr <= -bound else "undecided")
            self._follow_up["follow_up_decisions"].append((spot["x"], spot["y"], verdict, spot["presses"]))
            self._spots.pop(0)
        return []

    def _decide(self) -> list[tuple[float, float]]:
        p = self.params
        ev = self._evidence()
        self.perceived.update(self._follow_up)
        if ev is None:
            return []
        count = self.info.public.get("nodule_count")
        limit = int(count) if count is not None else p["max_reports"]
        if count is not None:
            # told how many nodules there are, the person names that many spots
            spots = self._clusters(*ev, threshold=-math.inf, limit=limit)
        else:
            # It reports what feels like a nodule: a spot it re-palpated and found to be one, or one clear enough
            # on its own (z_threshold); not what it re-palpated and found like its surroundings; and only spots
            # nearly as stiff as the clearest one felt (report_fraction).
            reach = p["cluster_radius_mm"] / 2.0
            verdicts = self._follow_up.get("follow_up_decisions", ())
            confirmed = [(x, y) for x, y, v, _n in verdicts if v == "nodule"]
            dismissed = [(x, y) for x, y, v, _n in verdicts if v == "none"]

            def near(sp, places) -> bool:
                return any(math.hypot(sp[0] - x, sp[1] - y) <= reach for x, y in places)

            spots = [
                sp for sp in self._clusters(*ev, threshold=0.0, limit=2 * limit)
                if (sp[2] >= p["z_threshold"] or near(sp, confirmed)) and not near(sp, dismissed)
            ]
            if spots and p["report_fraction"] > 0:
                clearest = max(peak for *_, peak in spots)
                spots = [sp for sp in spots if sp[3] >= p["report_fraction"] * clearest]
            spots = spots[:limit]
        self.perceived["reports"] = spots
        self.experience.append({"condition": self.info.condition, "cues": list(self.perceived.get("cues", [])),
                                "z_max": self.perceived.get("z_max", math.nan), "direct": self._direct})
        return [(x, y) for x, y, *_ in spots]

    # ------------------------------------------------------------------ questionnaires
    def answer(self, item: Mapping[str, Any], rng: np.random.Generator) -> int:
        """A code of the item's scale from the participant's own trials (see the module docstring)."""
        codes = sorted(int(c) for c in (item.get("codes") or [1, 2, 3, 4, 5]))
        key = f"{item.get('id', '')} {item.get('text', '')}".lower()
        if "combin" not in key or "force" not in key:
            return codes[len(codes) // 2]
        record = item.get("history")
        if record is None:
            return self._answer_from_memory(codes, rng)
        both: list[Mapping[str, Any]] = []
        force: list[Mapping[str, Any]] = []
        for row in record:
            if row.get("manual") or not row.get("duration_s"):
                continue
            told = _feedback_named(row)
            if told == {"force", "cursor"}:
                both.append(row)
            elif told == {"force"}:
                force.append(row)
        if not both or not force:
            return codes[0]
        weber = self.params["search_weber"]
        # how much faster spots were found with both feedbacks, as a judged (noisy) log ratio
        judged = math.log(_search_rate(both) / _search_rate(force)) + weber * float(rng.normal())
        steps = int(judged / math.log1p(weber)) if judged > 0 else 0  # in just-noticeable differences
        return codes[min(steps, len(codes) - 1)]

    def _answer_from_memory(self, codes: list[int], rng: np.random.Generator) -> int:
        """Without a stored record: from remembered percepts (stronger evidence with both cues perceived?)."""
        felt = [e for e in self.experience if not e["direct"] and math.isfinite(e["z_max"]) and e["z_max"] > 0]
        both = [e["z_max"] for e in felt if {"force", "cursor"} <= set(e["cues"])]
        force = [e["z_max"] for e in felt if e["cues"] == ["force"]]
        if not both or not force:
            return codes[0]
        weber = self.params["visual_weber"]
        judged = math.log(float(np.mean(both)) / float(np.mean(force))) + weber * float(rng.normal())
        steps = int(judged / math.log1p(weber)) if judged > 0 else 0
        return codes[min(steps, len(codes) - 1)]


def _depth_matched(felt: np.ndarray, seen: np.ndarray, survey: np.ndarray) -> np.ndarray:
    """Per press: a cue (the push felt, or the force the cursor's slowing reads) over what the tissue around
    gives at the same indentation.

    The maps' forces grow faster than the depth (about d^1.7 between 2 and 7 mm, Hertz-like; linear below
    the shallowest map), so force per depth is itself larger for a deeper press: a press held 4.7 mm deep
    (the first press of a PHF+FF trial, before the cursor ratchets up in the on/off push) read 26-42 %
    "stiffer" than its neighbours held at 1.7 mm, and was reported as a nodule at the block's corner where
    every trial starts; in FF and by hand the press-to-press depth scatter alone made force per depth vary
    by 3 % (SD) where the tissue is uniform. A person learns over the survey how hard the tissue pushes at
    each depth and compares each press with that: a smooth curve, quadratic in log force against log depth,
    fitted to the survey presses (a press held at a depth like no other pulls the curve to itself and so
    reads as ordinary rather than as stiff)."""
    ok = np.isfinite(felt) & np.isfinite(seen) & (felt > 0) & (seen > 0)
    ref = survey & ok
    out = np.full(len(felt), math.nan)
    if ref.sum() < 8:
        out[ok] = felt[ok] / seen[ok]
        return out
    x, y = np.log(np.where(ok, seen, 1.0)), np.log(np.where(ok, felt, 1.0))
    xm = float(np.mean(x[ref]))
    coef = np.polyfit(x[ref] - xm, y[ref], 2 if np.ptp(x[ref]) > 0.05 else 1)
    out[ok] = np.exp(y[ok] - np.polyval(coef, x[ok] - xm))
    return out


def _feedback_named(row: Mapping[str, Any]) -> set[str]:
    """The feedbacks a trial's condition was introduced with (its label, else its id): force, cursor or both."""
    name = str(row.get("label") or row.get("condition") or "").lower()
    told = set()
    if "force" in name:
        told.add("force")
    if "pseudo" in name or "cursor" in name:
        told.add("cursor")
    return told


def _search_rate(rows: list[Mapping[str, Any]]) -> float:
    """Spots found per second of searching over the trials (one added, so an empty search still counts)."""
    found = sum(float(r.get("reports") or 0) + 1.0 for r in rows)
    return found / sum(float(r["duration_s"]) for r in rows)
