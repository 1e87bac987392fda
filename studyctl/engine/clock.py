"""Clocks. The same engine code runs on a real monotonic clock (people, hardware) and on a
simulated one (virtual participants, tests) that advances as fast as the computation allows."""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    simulated: bool

    def now(self) -> float:
        """Seconds on this clock (monotonic)."""

    def sleep_until(self, t: float) -> None:
        """Return at (or just after) clock time ``t``."""


class RealClock:
    """Monotonic wall clock; sleeps coarsely then spins the last half-millisecond for precise pacing."""

    simulated = False

    def __init__(self) -> None:
        self._origin = time.perf_counter()

    def now(self) -> float:
        return time.perf_counter() - self._origin

    def sleep_until(self, t: float) -> None:
        remaining = t - self.now()
        if remaining > 0.0015:
            time.sleep(remaining - 0.001)
        while self.now() < t:
            pass


class SimulatedClock:
    """A clock that jumps to whatever time is asked for; a 90 s trial costs only its computation."""

    simulated = True

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)

    def now(self) -> float:
        return self._t

    def sleep_until(self, t: float) -> None:
        if t > self._t:
            self._t = float(t)

    def advance(self, dt: float) -> None:
        self._t += float(dt)
