"""The safety layer that stands between every controller and every device.

Whatever a controller commands, :meth:`SafetyLayer.filter` writes only values the device may take:

1. **Watchdog.** A tick whose time is not finite or earlier than the previous tick's, a tick that arrives
   more than ``deadline_factor`` periods after the previous one (the loop missed its deadline; measured
   from the last tick with a good time), a sensor sample older than the device's ``sensor_stale_s``, a fault the
   device reported while reading (``Observation.faults``, e.g. an ADC value outside its range) or a
   non-finite sensor value each put the device in its safe state and raise a ``device_fault`` event.
   When the cause clears, a ``device_recovered`` event is raised and the outputs ramp up again.
2. **Invalid values.** NaN, inf, or a non-number become the channel's safe value; a command that is not
   a mapping is treated as "everything safe". Channels the device lacks are never written.
3. **Limits.** Each channel is clamped to ``[low, high]``; force channels ``fx_n, fy_n, fz_n`` are scaled
   down together to the device's ``max_force_n`` (direction kept).
4. **Ramp-up on enable.** For ``ramp_up_s`` after enabling (or recovering), outputs are scaled from the
   safe value towards the command (0 → 1 linearly), as CHAI3D and OpenHaptics do after start-up.
5. **Rate of change.** A channel with ``max_rate_per_s`` moves at most that much per second of trial time.

Everything is logged as events (dicts with ``t``, ``kind`` and ``rule``) that the trial loop forwards to
the study log: faults and recoveries when they happen; clamping, invalid values and rate limiting when
they start and when they end (with the number of ticks affected), so a controller stuck at a limit at
1 kHz logs two events, not a thousand. :class:`Watchdog` is the thread-based backstop for real-time
loops: it commands the safe state if the loop stops calling in altogether.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.plugins.interfaces import DeviceLimits, Observation

log = logging.getLogger("studyctl.safety")

FORCE_CHANNELS = ("fx_n", "fy_n", "fz_n")


class SafetyLayer:
    """Clamp, sanitise, ramp and rate-limit commands; watch deadlines and sensors; log everything.

    Parameters
    ----------
    limits : DeviceLimits
        The device's output channels, force bound, sensor staleness and ramp-up time.
    period_s : float, optional
        The loop period; enables the missed-deadline check.
    deadline_factor : float
        A tick later than ``deadline_factor * period_s`` after the previous one is a missed deadline.
    auto_enable : bool
        Enable (and start the ramp-up) at the first :meth:`filter` call. With False, outputs stay safe
        until :meth:`enable` is called.
    """

    def __init__(
        self,
        limits: DeviceLimits,
        *,
        period_s: float | None = None,
        deadline_factor: float = 3.0,
        auto_enable: bool = True,
    ) -> None:
        self.limits = limits
        self._by_name = {c.name: c for c in limits.outputs}
        self.period_s = period_s
        self.deadline_factor = deadline_factor
        self.auto_enable = auto_enable
        self.events: list[dict[str, Any]] = []
        self.counts: dict[str, int] = {}
        self._lock = threading.Lock()
        self._enabled_at: float | None = None
        self._last_t: float | None = None
        self._last_out: dict[str, float] = {}
        self._active: dict[tuple[str, str], tuple[float, int]] = {}
        self._fault_causes: dict[str, float] = {}  # cause -> start time
        self._ramping = False
        self._rate_limited = any(c.max_rate_per_s is not None for c in limits.outputs)
        # Per-tick constants of the fast path (see filter): the channels with their bounds, and the force
        # channels the device has, in FORCE_CHANNELS order.
        self._names = frozenset(self._by_name)
        self._bounds = tuple((name, c.safe, c.low, c.high) for name, c in self._by_name.items())
        self._force_present = tuple(c for c in FORCE_CHANNELS if c in self._by_name)
        # The force bound and sensor age limit, read every tick (limits is frozen).
        self._max_force_n = limits.max_force_n
        self._stale_s = limits.sensor_stale_s

    # -- state -------------------------------------------------------------------------------------
    def enable(self, t: float) -> None:
        """Allow outputs from trial time ``t``, ramping up over the device's ``ramp_up_s``."""
        self._enabled_at = t
        self._last_out = self.safe_command()
        self._ramping = self.limits.ramp_up_s > 0
        self._event(t, "safety", "enabled", ramp_up_s=self.limits.ramp_up_s)

    def disable(self, t: float) -> None:
        """Hold every output at its safe value until :meth:`enable` is called again."""
        self._enabled_at = None
        self._event(t, "safety", "disabled")

    @property
    def enabled(self) -> bool:
        return self._enabled_at is not None

    @property
    def faulted(self) -> bool:
        return bool(self._fault_causes)

    def fault_duration(self, t: float) -> float:
        """How long (s) the device has been held in its safe state by a fault, 0 if it is not."""
        if not self._fault_causes:
            return 0.0
        return t - min(self._fault_causes.values())

    def safe_command(self) -> dict[str, float]:
        return self.limits.safe_command()

    def drain_events(self) -> list[dict[str, Any]]:
        """Return and forget the events raised since the last call (thread-safe)."""
        with self._lock:
            out, self.events = self.events, []
        return out

    # -- logging -----------------------------------------------------------------------------------
    def record(self, t: float, kind: str, rule: str, **detail: Any) -> None:
        """Log an event raised outside :meth:`filter` (e.g. by the :class:`Watchdog` thread)."""
        self._event(t, kind, rule, **detail)

    def _event(self, t: float, kind: str, rule: str, **detail: Any) -> None:
        event = {"t": t, "kind": kind, "rule": rule, **detail}
        with self._lock:
            self.events.append(event)
        level = logging.WARNING if kind == "device_fault" else logging.INFO
        log.log(level, "t=%.4f %s %s %s", t, kind, rule, detail)

    def _mark(self, t: float, rule: str, channel: str, fired: bool, **detail: Any) -> None:
        """Start/end bookkeeping for per-channel rules, so persistent conditions log twice, not per tick."""
        key = (rule, channel)
        if fired:
            self.counts[rule] = self.counts.get(rule, 0) + 1
            if key in self._active:
                start, n = self._active[key]
                self._active[key] = (start, n + 1)
            else:
                self._active[key] = (t, 1)
                self._event(t, "safety", rule, channel=channel, state="start", **detail)
        elif key in self._active:
            start, n = self._active.pop(key)
            self._event(t, "safety", rule, channel=channel, state="end", ticks=n, duration_s=t - start)

    def _quiet(self, t: float, rule: str, channel: str) -> None:
        """The rule did not fire: close its start/end pair if one is open (cheap when none is)."""
        if self._active and (rule, channel) in self._active:
            self._mark(t, rule, channel, False)

    # -- watchdog ----------------------------------------------------------------------------------
    def _check_watchdog(self, t: float, obs: Observation | None) -> dict[str, dict[str, Any]]:
        causes: dict[str, dict[str, Any]] = {}
        if self.period_s is not None and self._last_t is not None:
            gap = t - self._last_t
            if gap > self.deadline_factor * self.period_s:
                causes["missed_deadline"] = {"gap_s": gap, "period_s": self.period_s,
                                             "missed": max(round(gap / self.period_s) - 1, 1)}
                self.counts["missed_deadline"] = self.counts.get("missed_deadline", 0) + 1
        if obs is not None:
            if obs.sample_t is not None and t - obs.sample_t > self.limits.sensor_stale_s:
                causes["stale_sensor"] = {"age_s": t - obs.sample_t, "limit_s": self.limits.sensor_stale_s}
            if obs.faults:
                causes["sensor_fault"] = {"faults": list(obs.faults)}
            if not _all_finite_floats(obs.values.values()):
                bad = [
                    k
                    for k, v in obs.values.items()
                    if not (type(v) is float and v - v == 0.0) and not _finite_number(v)
                ]
                if bad:
                    causes["sensor_non_finite"] = {"channels": bad}
        return causes

    def _update_faults(self, t: float, causes: dict[str, dict[str, Any]]) -> None:
        for cause, detail in causes.items():
            if cause not in self._fault_causes:
                self._fault_causes[cause] = t
                self._event(t, "device_fault", cause, **detail)
        cleared = [c for c in self._fault_causes if c not in causes]
        for cause in cleared:
            start = self._fault_causes.pop(cause)
            self._event(t, "device_recovered", cause, duration_s=t - start)
        if cleared and not self._fault_causes and self.enabled:
            # Recovering is like enabling again: start from safe and ramp up.
            self._enabled_at = t
            self._last_out = self.safe_command()
            self._ramping = self.limits.ramp_up_s > 0

    # -- the filter --------------------------------------------------------------------------------
    def filter(self, command: Mapping[str, float] | Any, t: float, obs: Observation | None = None) -> dict[str, float]:
        """The values to write to the device this tick for ``command`` at trial time ``t``.

        Never raises for bad commands or sensor data: it returns the safe state and logs why.
        """
        last_t = self._last_t
        # Time itself is input: a non-finite tick time or one earlier than the last tick puts the device in its
        # safe state for that tick (a device_fault), and a NaN tick is not remembered, so the gap from the last
        # good tick to the next is still measured (and counted as a missed deadline when it is one).
        try:
            bad_time = not (t - t == 0.0) or (last_t is not None and t < last_t)
        except TypeError:
            bad_time = True
        if bad_time:
            return self._time_fault(t, last_t)
        if last_t is None and self._enabled_at is None and self.auto_enable:
            self.enable(t)
        # Watchdog: the usual tick has no cause, so its conditions are tested inline here and
        # _check_watchdog (which builds the causes and their details) runs only when one may hold.
        period = self.period_s
        if (
            (period is not None and last_t is not None and t - last_t > self.deadline_factor * period)
            or (
                obs is not None
                and (
                    (obs.sample_t is not None and t - obs.sample_t > self._stale_s)
                    or obs.faults
                    or not _all_finite_floats(obs.values.values())
                )
            )
        ):
            causes = self._check_watchdog(t, obs)
            if causes or self._fault_causes:
                self._update_faults(t, causes)
        elif self._fault_causes:
            self._update_faults(t, {})
        dt = None if last_t is None else t - last_t
        self._last_t = t
        active = self._active
        if type(command) is dict and not active and command.keys() <= self._names:
            pass  # the usual tick: a dict of known channels and no open start/end pair, nothing to log
        else:
            if not isinstance(command, Mapping):
                self._mark(t, "invalid_command", "*", True, type=type(command).__name__)
                command = {}
            else:
                self._quiet(t, "invalid_command", "*")
            unknown = [k for k in command if k not in self._by_name]
            if unknown:
                self._mark(t, "unknown_channel", "*", True, channels=sorted(map(str, unknown)))
            else:
                self._quiet(t, "unknown_channel", "*")
        if self._fault_causes or self._enabled_at is None:
            out = self.safe_command()
            self._last_out = dict(out)
            return out

        values: dict[str, float] = {}
        if not active:
            # Fast path: no start/end pair is open, so every _quiet below would be a no-op. A channel whose
            # command is a finite float inside its bounds passes unchanged; any other takes the full checks.
            get = command.get
            for name, safe, low, high in self._bounds:
                raw = get(name, safe)
                kind = type(raw)
                if kind is float:
                    if raw - raw == 0.0 and low <= raw <= high:
                        values[name] = raw
                        continue
                elif kind is _F64 and math.isfinite(raw) and low <= raw <= high:
                    values[name] = float(raw)  # as _check_channel does for any finite number
                    continue
                values[name] = self._check_channel(t, name, self._by_name[name], raw)
        else:
            for name, limit in self._by_name.items():
                values[name] = self._check_channel(t, name, limit, command.get(name, limit.safe))

        max_force = self._max_force_n
        if max_force is not None:
            present = self._force_present
            if len(present) == 3:
                # the three force channels: the same left-to-right sum of squares as sum() below, without
                # building a list every tick
                a, b, c = present
                norm = math.sqrt(values[a] ** 2 + values[b] ** 2 + values[c] ** 2)
            else:
                norm = math.sqrt(sum([values[c] ** 2 for c in present]))
            if norm > max_force:
                self._mark(t, "force_norm", "force", True, norm_n=norm, max_n=max_force)
                scale = max_force / norm
                for c in present:
                    values[c] *= scale
            elif active:  # _active is only ever mutated in place, so this is the same dict
                self._quiet(t, "force_norm", "force")

        if self._ramping:
            ramp = self.limits.ramp_up_s
            s = min(max((t - self._enabled_at) / ramp, 0.0), 1.0)
            for name, limit in self._by_name.items():
                values[name] = limit.safe + s * (values[name] - limit.safe)
            if s >= 1.0:
                self._ramping = False
                self._event(t, "safety", "ramp_done", ramp_up_s=ramp)

        if self._rate_limited:
            step_dt = dt if dt is not None and dt > 0 else self.period_s
            for name, limit in self._by_name.items():
                if limit.max_rate_per_s is None or step_dt is None or name not in self._last_out:
                    continue
                prev = self._last_out[name]
                max_step = limit.max_rate_per_s * step_dt
                delta = values[name] - prev
                if abs(delta) > max_step:
                    self._mark(t, "rate_limited", name, True, requested=values[name], rate_per_s=limit.max_rate_per_s)
                    values[name] = min(max(prev + math.copysign(max_step, delta), limit.low), limit.high)
                else:
                    self._quiet(t, "rate_limited", name)

        self._last_out = values
        # only the rate limit reads _last_out: without one the caller may have the dict itself (no copy a tick)
        return dict(values) if self._rate_limited else values

    def _time_fault(self, t: Any, last_t: float | None) -> dict[str, float]:
        finite = _finite_number(t)
        cause = "time_backwards" if finite else "time_non_finite"
        at = float(t) if finite else (last_t if last_t is not None else 0.0)
        self.counts[cause] = self.counts.get(cause, 0) + 1
        if cause not in self._fault_causes:
            self._fault_causes[cause] = at
            self._event(at, "device_fault", cause, tick_t=repr(t), last_t=last_t)
        if finite:
            self._last_t = float(t)  # the clock went back: measure the next gaps from here
        out = self.safe_command()
        self._last_out = dict(out)
        return out

    def _check_channel(self, t: float, name: str, limit: Any, raw: Any) -> float:
        """One channel's command made finite and clamped to its bounds, with its start/end bookkeeping."""
        if type(raw) is float and raw - raw == 0.0:  # a finite float
            value = raw
            self._quiet(t, "non_finite_command", name)
        elif _finite_number(raw):
            value = float(raw)
            self._quiet(t, "non_finite_command", name)
        else:
            self._mark(t, "non_finite_command", name, True, value=repr(raw))
            value = limit.safe
        if value < limit.low or value > limit.high:
            clamped = limit.low if value < limit.low else limit.high
            self._mark(t, "clamped", name, True, value=value, low=limit.low, high=limit.high)
            value = clamped
        else:
            self._quiet(t, "clamped", name)
        return value


_F64 = np.float64
_FLOATS = frozenset({float, np.float64})


def _all_finite_floats(values: Any) -> bool:
    """True when every value is a finite float (Python or numpy float64), checked in C: the set of their types
    and an exact sum (``math.fsum`` gives NaN or inf for a NaN or ±inf term, raises for inf − inf or an
    overflowing sum; it never warns like numpy arithmetic). False is only "not sure": an overflow, an int, a
    bool (which is not a sensor reading) or another type go to the per-channel check."""
    if not _FLOATS.issuperset(map(type, values)):  # no set built: each type is looked up as it comes
        return False
    try:
        return math.isfinite(math.fsum(values))
    except (OverflowError, ValueError):
        return False


def _finite_number(value: Any) -> bool:
    if isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except (TypeError, OverflowError):  # OverflowError: an int too large for a float (10**400)
        return False


class Watchdog:
    """A thread that calls ``on_timeout`` once when :meth:`kick` has not been called for ``timeout_s``.

    The real-time backstop for a loop that stalls inside a plugin (the safety layer's deadline check
    only runs when the loop comes back). ``on_timeout`` should command the safe state; it is re-armed
    by the next :meth:`kick`. Uses the monotonic clock.
    """

    def __init__(self, timeout_s: float, on_timeout: Callable[[float], None]) -> None:
        if not timeout_s > 0:
            raise ModelParameterError(f"watchdog timeout must be > 0 s, got {timeout_s!r}")
        self.timeout_s = timeout_s
        self.on_timeout = on_timeout
        self.trips = 0
        self._last = time.monotonic()
        self._tripped = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="studyctl-watchdog", daemon=True)

    def start(self) -> Watchdog:
        self._last = time.monotonic()
        self._thread.start()
        return self

    def kick(self) -> None:
        self._last = time.monotonic()
        self._tripped = False

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)

    def _run(self) -> None:
        poll = min(self.timeout_s / 4, 0.01)
        while not self._stop.wait(poll):
            late = time.monotonic() - self._last
            if late > self.timeout_s and not self._tripped:
                self._tripped = True
                self.trips += 1
                try:
                    self.on_timeout(late)
                except Exception:  # the backstop must never die silently
                    log.exception("watchdog on_timeout failed")
