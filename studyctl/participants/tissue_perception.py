"""What the virtual tissue palpator senses in one press (:mod:`studyctl.participants.tissue_palpator`).

:class:`PressPerception` is the palpator's per-press perception: when the push felt at the bottom is steady
(a criterion over time), how long the press is held (until the fused judgement is precise enough), and what
the press is recorded as (the strongest push with the depth at that moment, the cursor's slowing over the end of
its descent, each with the person's sensory noise). :func:`_depth_matched` compares a cue with what the tissue
around gives at the same depth. :class:`AirRatios` keeps the air ticks' cursor-over-hand travel ratios sorted, for
:meth:`PressPerception._r0`'s median. No decisions about spots: those are in :mod:`.tissue_decision`.
"""

from __future__ import annotations

import math
from array import array
from bisect import bisect_right
from typing import Any

import numpy as np

from studyctl.participants.exact_mean import median_of_sorted


class PressPerception:
    """Mixin of :class:`~studyctl.participants.tissue_palpator.VirtualTissuePalpator`: per-press perception."""

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
        return self._air_ratios.median(self._air_dc, self._air_dh)

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


class AirRatios:
    """The cursor-over-hand travel ratios of the air ticks, kept sorted for their median (``R₀``).

    The palpator appends each air tick's cursor and hand travel to two float buffers and looks at ``R₀`` at every
    press bottom and every look at the evidence. ``np.median`` of all the ratios divided and partitioned up to ~10,000
    of them at each look (5 % of the person's CPU at seed 003); here each look only merges in the ratios appended since
    the last one (the same divisions), so the sorted array holds the same values and its middle is ``np.median``'s
    (:func:`~studyctl.participants.exact_mean.median_of_sorted`)."""

    def __init__(self) -> None:
        self._sorted = np.empty(0)
        self._buffers: tuple[array, array] | None = None  # the buffers merged from (a test may swap them)

    def median(self, dc: array, dh: array) -> float:
        """``float(np.median(np.frombuffer(dc) / np.frombuffer(dh)))`` of the two equally long, non-empty buffers."""
        done = self._sorted.size
        if self._buffers is None or self._buffers[0] is not dc or self._buffers[1] is not dh or len(dc) < done:
            self._sorted, self._buffers, done = np.empty(0), (dc, dh), 0
        if len(dc) > done:
            # views of the buffers live only in this line: a buffer with a view cannot grow
            new = np.frombuffer(dc)[done:] / np.frombuffer(dh)[done:len(dc)]
            new.sort()
            self._sorted = np.insert(self._sorted, np.searchsorted(self._sorted, new), new)
        return median_of_sorted(self._sorted)


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
