"""Lab Streaming Layer outlets for a session (optional extra ``lsl``: ``pip install 'studyctl[lsl]'``).

So that a lab can align the haptic record with EEG, EMG or eye tracking recorded by LSL (LabRecorder), a session run
with ``--lsl`` publishes two kinds of stream while it records:

- ``studyctl-markers`` (type ``Markers``, one string channel, irregular rate): every event the session records, as
  JSON ``{"kind", "session", "trial", ...}`` (trial starts and ends, scans, reports, device faults …);
- ``studyctl-device`` (type ``Haptics``, float32, at the loop rate): every sample a trial records, one channel per
  recorded channel (names and units in the stream's ``desc/channels``); a new outlet starts when a trial records a
  different set of channels.

Time stamps are LSL's clock (``local_clock()``, the monotonic clock): a trial time ``t`` is placed at the trial's
start on that clock plus ``t``. The servo process reports the loop's time 0 on the same clock (``servo_clock``
event, taken where the loop takes its time 0), so samples that arrive in batches keep their own times: a sample's
stamp is the monotonic time at which the loop read it.

:class:`LslRecorder` wraps the session's recorder: everything is recorded as before, and also published.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from typing import Any

from studyctl.errors import UsageError

EXTRA_HINT = "pip install 'studyctl[lsl]'"
# events too frequent or too bulky to be markers (the samples stream carries the data)
SKIPPED = frozenset({"scene_truth", "participant_memory", "device_identity"})


def load_pylsl() -> Any:
    try:
        import pylsl  # noqa: PLC0415 - optional dependency
    except ImportError as exc:
        raise UsageError(f"--lsl needs the Lab Streaming Layer bindings: {EXTRA_HINT} ({exc})") from None
    except (OSError, RuntimeError) as exc:  # pylsl is there, liblsl could not be loaded
        raise UsageError(f"--lsl: liblsl could not be loaded ({exc}); reinstall with {EXTRA_HINT}") from None
    return pylsl


def device_source_id(source: str, channels: Sequence[str]) -> str:
    """The device stream's LSL source id: the same for the same session and channels in every process, so that a
    recorder (LabRecorder) picks the stream up again when a session resumes after a crash. (Python's ``hash()`` of
    strings is salted per process, so it cannot serve here.)"""
    digest = hashlib.sha256("\x1f".join(channels).encode()).hexdigest()[:8]
    return f"{source}:device:{digest}"


class LslStreams:
    """The outlets of one session, created lazily; ``source`` makes their ids unique and stable per session."""

    def __init__(self, source: str, pylsl: Any = None) -> None:
        self.lsl = pylsl or load_pylsl()
        self.source = source
        info = self.lsl.StreamInfo("studyctl-markers", "Markers", 1, self.lsl.IRREGULAR_RATE, "string",
                                   f"{source}:markers")
        self.markers = self.lsl.StreamOutlet(info)
        self._device: Any = None
        self._channels: tuple[str, ...] = ()
        self.rate_hz = 0.0
        self.trial_zero: float | None = None  # LSL time of trial time 0
        self.sent_markers = 0
        self.sent_samples = 0

    def clock(self) -> float:
        return float(self.lsl.local_clock())

    def marker(self, kind: str, payload: Mapping[str, Any], stamp: float) -> None:
        text = json.dumps({"kind": kind, **{k: v for k, v in payload.items()}}, default=str, separators=(",", ":"))
        self.markers.push_sample([text], stamp)
        self.sent_markers += 1

    def sample(self, channels: Sequence[str], values: Sequence[float], stamp: float, rate_hz: float) -> None:
        channels = tuple(channels)
        if channels != self._channels or self._device is None:
            info = self.lsl.StreamInfo("studyctl-device", "Haptics", len(channels), float(rate_hz), "float32",
                                       device_source_id(self.source, channels))
            chans = info.desc().append_child("channels")
            for name in channels:
                ch = chans.append_child("channel")
                ch.append_child_value("label", name)
                ch.append_child_value("unit", _unit(name))
            self._device = self.lsl.StreamOutlet(info)
            self._channels, self.rate_hz = channels, rate_hz
        self._device.push_sample([float(v) for v in values], stamp)
        self.sent_samples += 1


def _unit(channel: str) -> str:
    for suffix, unit in (("_n", "N"), ("_mm_s", "mm/s"), ("_mm", "mm"), ("_pct", "%"), ("_kpa", "kPa"),
                         ("_psi", "psi"), ("_s", "s"), ("_hz", "Hz")):
        if channel.endswith(suffix):
            return unit
    return ""


class _Samples:
    def __init__(self, inner: Any, owner: LslRecorder) -> None:
        self.inner = inner
        self.streams = owner.streams
        self.owner = owner

    def write(self, t: float, values: Mapping[str, float]) -> None:
        self.inner.write(t, values)
        zero = self.streams.trial_zero
        self.streams.sample(tuple(values), tuple(values.values()),
                            (zero if zero is not None else self.streams.clock() - t) + t, self.owner.rate_hz)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


class LslRecorder:
    """A session recorder that also publishes what it records to LSL (see the module docstring)."""

    def __init__(self, inner: Any, streams: LslStreams) -> None:
        self.inner = inner
        self.streams = streams
        self.rate_hz = 1000.0

    def event(self, kind: str, payload: Mapping[str, Any], *args: Any, **kw: Any) -> Any:
        s = self.streams
        arrived = s.clock()  # before the inner recorder writes (a store commit can take milliseconds)
        out = self.inner.event(kind, payload, *args, **kw)
        t = kw.get("t", args[0] if args else None)
        trial = kw.get("trial_id")
        if kind == "servo_clock":
            s.trial_zero = float(payload["monotonic_zero"])
        elif kind == "trial_loop_start":
            self.rate_hz = float(payload.get("rate_hz") or self.rate_hz)
            if s.trial_zero is None or (t is not None and s.clock() - (s.trial_zero + float(t)) > 5.0):
                s.trial_zero = arrived - float(t or 0.0)  # in this process: the event arrives as it happens
        if kind not in SKIPPED:
            now = s.clock()
            stamp = s.trial_zero + float(t) if (trial is not None and t is not None and s.trial_zero) else now
            s.marker(kind, {"session": self.inner.state().session_id, "trial": trial, "t": t,
                            **_small(payload)}, min(stamp, now))
        if kind == "trial_loop_end":
            s.trial_zero = None
        return out

    def trial_started(self, position: int, attempt: int, t: float, info: Mapping[str, Any]) -> int:
        tid = self.inner.trial_started(position, attempt, t, info)
        self.streams.marker("trial_start", {"session": self.inner.state().session_id, "trial": tid, "t": t,
                                            "position": position, **_small(info)}, self.streams.clock())
        return tid

    def trial_finished(self, trial_id: int, status: str, outcome: Mapping[str, Any], *args: Any, **kw: Any) -> Any:
        out = self.inner.trial_finished(trial_id, status, outcome, *args, **kw)
        self.streams.marker("trial_end", {"session": self.inner.state().session_id, "trial": trial_id,
                                          "status": status, **_small(outcome)}, self.streams.clock())
        return out

    def samples(self, trial_id: int, channels: list[str]) -> Any:
        return _Samples(self.inner.samples(trial_id, channels), self)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def _small(payload: Mapping[str, Any]) -> dict[str, Any]:
    """The scalar parts of an event payload (poses and plans stay in the database)."""
    return {k: v for k, v in payload.items() if isinstance(v, str | int | float | bool) or v is None}

