"""How the seed-003 palpator's hand moves: planned moves in the air, steered presses, and what it learns of the press.

A mixin of :class:`~studyctl.participants.tissue_palpator.VirtualTissuePalpator`, split from it along the line
between the motor system (this module: where the hand goes next, tick by tick) and the trial's phases, perception and
decisions (the palpator and its other mixins). It reads the palpator's per-trial state (``_hand``, ``_goal``,
``_target``, ``_motor``, ``_phase``, ``_press``, ``_press_yield``) and ``params``; it draws no random numbers.
"""

from __future__ import annotations

import math
from typing import Any


class HandMotor:
    """The hand's motor control; see the module docstring for the state it shares with the palpator."""

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
        phase = self._phase
        tx, ty, tz = self._target
        ex, ey, ez = tx - ctrl[0], ty - ctrl[1], tz - ctrl[2]
        k = m["gain"] * dt
        kz = k
        if phase == "press":
            # adapted to how little the watched point yields per hand millimetre in this condition (the cursor's
            # pseudo-haptic slowing, the hand pushed back by rendered force): the press keeps its planned pace
            kz = k / self._press_yield
        elif phase == "dwell":
            # holding a press: slow depth corrections only, well below the hand's own resonance against the tissue
            kz = k * self.params["hold_gain_ratio"]
        vx, vy, vz = ex * k, ey * k, ez * kz
        lateral = (self.params["slide_speed_mm_s"] * m["tempo"] if phase == "slide" else m["move"]) * dt
        vertical = m["press"] * dt
        lat = math.hypot(vx, vy)
        if lat > lateral:
            vx, vy = vx * lateral / lat, vy * lateral / lat
        # vz = max(-vertical, min(vertical, vz)) without the two calls, to the bit: min and max return their first
        # argument unless the second is strictly smaller / larger (so also for NaN and signed zeros)
        if not vz < vertical:
            vz = vertical
        if not vz > -vertical:
            vz = -vertical
        h[0] += vx
        h[1] += vy
        h[2] += vz

    def _felt_depth(self, ctrl: tuple[float, float, float], handle: tuple[float, float, float],
                    force: float) -> tuple[float, float, float]:
        """``press_steer: felt``: the point a press is steered by, once a push is felt: the cursor's depth when the
        push was first felt, deepened by the hand's own travel since (proprioception). Before any push, and where the
        cursor follows the hand, it is the cursor itself. The indentation a stiffness is judged against stays the
        one seen on the cursor: with pseudo-haptics a stiffer spot slows the cursor, so at a given hand travel the
        tool indents it less and the push rendered there is weaker; force over hand travel would cancel much of the
        contrast (trial loop, PHF+FF: 33 nodules of 72 against 50)."""
        contact = self._press.get("felt_at")
        if contact is None:
            if force <= 0.02:  # nothing felt yet, as _steady's threshold
                return ctrl
            contact = self._press["felt_at"] = (ctrl[2], handle[2])
        # The hand's travel counts millimetre for millimetre. Read at the cursor's learnt yield in the tissue instead
        # (a forward model: press the hand as far as took the cursor to depth before), the hand pressed further
        # against the push and the press was as slow as the cursor-steered one (trial loop, PHF+FF: 198 s, 47
        # nodules of 72, against 149 s, 46 at one to one and 194 s, 50 steered by the cursor).
        return (ctrl[0], ctrl[1], contact[0] - (contact[1] - handle[2]))

    def _adapt_press_gain(self, press: dict[str, Any], ctrl: tuple[float, float, float]) -> None:
        """Learn from this press how far the watched point went into the tissue per millimetre the hand was told
        to go (visuomotor gain adaptation: people rescale their movements to a changed cursor gain within a few
        movements, Krakauer et al. 2000), at ``press_adaptation`` per press, the boost at most
        ``max_press_boost``."""
        rate = self.params["press_adaptation"]
        if rate <= 0 or "in_at" not in press:
            return
        c0, h0 = press["in_at"]
        told = h0 - self._hand[2]
        if told < 0.5:  # too little travel in the tissue to see a gain
            return
        seen = min(max((c0 - ctrl[2]) / told, 1.0 / self.params["max_press_boost"]), 1.0)
        self._press_yield += rate * (seen - self._press_yield)

    def _plan_move(self, ctrl: tuple[float, float, float]) -> None:
        """Hand goal that brings the watched point to the target, never lower than the target height (a
        force pushing the hand back in the tissue vanishes in the air)."""
        t, h = self._target, self._hand
        self._goal = (h[0] + t[0] - ctrl[0], h[1] + t[1] - ctrl[1], max(h[2] + t[2] - ctrl[2], t[2]))

    def _goal_reached(self) -> bool:
        return self._goal is not None and math.dist(self._goal, self._hand) < 1e-9
