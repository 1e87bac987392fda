"""The sliding survey (:mod:`studyctl.participants.tissue_palpator`): where the cursor is seen to slow in the
tissue, the palpator slides the tool along each survey line at depth and reads where the cursor slows sideways.

Why: seed 003 §2.4 says people palpate by sliding and pressing, and its force rendering "assumes a constant
palpation velocity" (§2.5); its pseudo-haptic cursor slows sideways "towards a hard area" (Table 1:
``d_m(x, y) = R_n · D(x, y)`` while the tissue under the cursor gets stiffer, the controller's ``lateral_ratio:
normal``). A cursor that slows while the hand keeps its pace is felt as a bump (Lécuyer, Burkhardt & Etienne 2004,
CHI: bumps and holes from cursor speed alone). Pressing point by point, by contrast, reads one number per press.

The person starts as always, with a press; if that press showed the cursor lagging the hand (pseudo-haptics on),
the rest of the survey is slid: each line is pressed into at its start and slid to its end with the hand at
``slide_speed_mm_s`` (times the tempo), steered by the cursor. Every ``slide_window_mm`` of cursor travel is one
survey record: the hand's sideways travel over the cursor's (the slowing; ``visual_weber`` per ``judge_time_s``
watched, evidence growing as 1/√time, so a window slid past quickly is read coarsely), the depth the cursor was
at, and with force feedback the strongest push felt over the window with the depth then. With no cursor slowing
(force feedback alone, by hand) nothing changes. A slid survey ends without re-palpation: its records are not
comparable with a press's.

With ``slide_damping`` above 1 the person holds the stylus more steadily while sliding against a felt push
(the device's ``grip_damping`` input raises the hand's damping, not its stiffness; the relaxed hold's damping
ratio is 0.33). People co-contract against unstable interaction (Burdet et al. 2001), and the hand's viscosity
rises with muscle activation (Tsuji et al. 1995). What it corrects, as measured (seed 101's slide ticks, Table 1):
not a bounce (the hand's tick-to-tick depth jitter over plain tissue is 0.049 mm without force and 0.045 mm with
it, and the cursor is slowed on the same share of ticks), but the push lifting the spring-held hand as it rises
towards a nodule, so that with the relaxed hold the cursor is slowed on fewer ticks approaching a nodule than
leaving it (56 % against 65 %; 64 % against 45 % at 3).
"""

from __future__ import annotations

import math
from typing import Any


class SlideSurvey:
    """Mixin of :class:`~studyctl.participants.tissue_palpator.VirtualTissuePalpator`: the sliding survey."""

    def _slide_switch(self, press: dict[str, Any]) -> None:
        """After the first survey press: slide the rest of the survey if the person slides (``slide_survey``) and
        this press saw the cursor lag the hand. The probe press is not kept (a press's slowing is read over a
        descent, a slide's sideways: the two are not one cue)."""
        if not self.params["slide_survey"] or self._slide_mode or self._slide_checked or self._stage != "survey":
            return
        track = press.get("track") or []
        if len(track) < 2 or track[-1][0] <= 0.5:
            return
        lag = self._r0() * track[-1][1] / track[-1][0]  # hand over cursor travel, as R0 maps it (1: no slowing)
        if lag <= 1.05:
            return
        self._slide_probe_lag = lag - 1.0
        self._slide_mode = True
        self._presses.pop()
        lines: list[list[tuple[float, float]]] = [[(press["x"], press["y"])]]
        for x, y in reversed(self._plan):
            if lines[-1] and abs(lines[-1][-1][1] - y) > 1e-9:
                lines.append([])
            lines[-1].append((x, y))
        starts, self._slide_ends = [], {}
        for line in lines:
            if len(line) >= 2:
                starts.append(line[0])
                self._slide_ends[line[0]] = line[-1]
        self._plan = starts[::-1]  # pop() from the end
        # the press points, kept for going back to pressing if the first slide shows no sideways slowing
        self._slide_points = [pt for line in lines for pt in line][1:]

    def _slide_start(self, press: dict[str, Any], ctrl) -> bool:
        """At a line start's bottom: slide to the line's end (returns whether a slide began)."""
        end = self._slide_ends.get((press["x"], press["y"])) if self._slide_mode else None
        if end is None:
            return False
        self._target = (end[0], end[1], self._target[2])
        self._goal = None
        press["slide_from"] = len(self._presses)
        press["slide"] = {"end": end, "prev": None, "win": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]}
        length = math.dist(end, (ctrl[0], ctrl[1]))
        # a slide that has not arrived after three times its planned duration (a cursor slowed to a third) is over
        press["slide_limit"] = 3.0 * length / max(self.params["slide_speed_mm_s"] * self._motor["tempo"], 1e-9)
        self._phase, self._phase_t = "slide", 0.0
        return True

    def _slide_check(self, first_record: int) -> None:
        """After the first slid line: a person who saw the cursor slow sideways by less than a quarter of what the
        probe press showed (median lag ``R₀·q − 1`` of the line's windows; CHOSEN) goes back to pressing the
        remaining points (the line just slid included); its windows are dropped. A controller that slows only the
        normal moves (``lateral_ratio: horizontal``) gives a slide next to nothing to read: measured, a median
        sideways lag of 0.05 against ~0.4 by Table 1 and ~0.6 for a press."""
        if self._slide_checked:
            return
        self._slide_checked = True
        lags = sorted(self._r0() * r["ratio"] - 1.0 for r in self._presses[first_record:])
        if lags and lags[len(lags) // 2] > 0.25 * self._slide_probe_lag:
            return
        del self._presses[first_record:]
        self._slide_mode = False
        self._plan = self._slide_points[::-1]  # nothing of it was pressed yet; pop() from the end

    def _grip(self, force: float) -> float | None:
        """The damping factor to give the device this tick, or None (unchanged): ``slide_damping`` while sliding
        with a push felt, the relaxed 1 otherwise; None throughout when ``slide_damping`` is 1 (nothing sent)."""
        firm = self.params["slide_damping"]
        if firm == 1.0:
            return None
        grip = firm if self._phase == "slide" and (force > 0.0 or self._grip_held != 1.0) else 1.0
        if grip == self._grip_held:
            return None
        self._grip_held = grip
        return grip

    def _slide_tick(self, press: dict[str, Any], ctrl, cursor, handle, force: float) -> bool:
        """One tick of a slide: travel added to the current window, a window closed every ``slide_window_mm`` of
        cursor travel; returns whether the slide is over (the cursor at the line's end, or out of time)."""
        s = press["slide"]
        if cursor is not None and handle is not None:
            prev = s["prev"]
            s["prev"] = (cursor[0], cursor[1], handle[0], handle[1])
            if prev is not None:
                w = s["win"]  # hand travel, cursor travel, time, x sum, y sum, strongest push, depth at it
                w[0] += math.hypot(handle[0] - prev[2], handle[1] - prev[3])
                w[1] += math.hypot(cursor[0] - prev[0], cursor[1] - prev[1])
                w[2] += self._dt
                if w[2] <= self._dt or force > w[5]:
                    w[5], w[6] = force, press["h"] - ctrl[2]
                if w[1] >= self.params["slide_window_mm"]:
                    self._slide_record(press, cursor)
        end = s["end"]
        return math.hypot(ctrl[0] - end[0], ctrl[1] - end[1]) <= self.params["tolerance_mm"] or (
            self._phase_t >= press["slide_limit"]
        )

    def _slide_record(self, press: dict[str, Any], cursor) -> None:
        """One survey record from the window just slid (its noise drawn from the trial's rng)."""
        p = self.params
        rng = self.rng
        hand, seen, watched, _x, _y, push, push_depth = press["slide"]["win"]
        press["slide"]["win"] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        # evidence accumulates as 1/√time both ways: a window watched for less than one judgement's time is read
        # more coarsely (a 4 mm window slid at 47 mm/s is watched for 85 ms)
        scale = math.sqrt(p["judge_time_s"] / max(watched, 1e-3))
        half = 0.5 * p["slide_window_mm"]
        # the window's middle, half a window back along the slide from where the cursor is now
        ex, ey = press["slide"]["end"]
        d = math.hypot(ex - cursor[0], ey - cursor[1])
        ux, uy = ((ex - cursor[0]) / d, (ey - cursor[1]) / d) if d > 1e-9 else (0.0, 0.0)
        depth = press["h"] - cursor[2]
        row = {"x": cursor[0] - half * ux, "y": cursor[1] - half * uy, "force": math.nan, "ratio": math.nan,
               "stage": self._stage}
        noise = scale * math.hypot(p["visual_weber"], p["hand_weber"])
        row["ratio"] = hand / seen * (1.0 + noise * float(rng.normal()))
        row["ratio_seen"] = depth * (1.0 + p["depth_weber"] * float(rng.normal()))
        if push > 0.0 and push_depth > 0.2:
            felt = push * (1.0 + scale * p["force_weber"] * float(rng.normal()))
            seen_depth = push_depth * (1.0 + scale * p["depth_weber"] * float(rng.normal()))
            row["force"] = felt / seen_depth
            row["felt"], row["seen"] = felt, seen_depth
        self._presses.append(row)
