"""``studyctl device list|check``: what devices this installation can drive, and a device's health.

:func:`check_device` connects to a device (or its emulator), reports its identity and limits, runs its loop in the
servo process for a few seconds at its rate and measures the rate and period jitter, and exercises the safety
layer on the device itself: a command beyond the limits (must be clamped), a NaN command (must become the safe
value) and a stalled loop (the watchdog must put the device in its safe state and raise ``device_fault``). Every
check is judged from what the loop recorded (events and the values actually written), not from what was asked.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from studyctl.engine.trial_loop import TIMING_FAULTS
from studyctl.errors import UsageError
from studyctl.plugins.interfaces import Controller, Observation, TrialInfo

# Fractions of the check's duration: safe commands, then over the limits, then NaN, then a stall.
PHASES = {"over_limit": (0.45, 0.6), "nan": (0.6, 0.72), "stall_at": 0.8}


class CheckController(Controller):
    """Commands the sequence :data:`PHASES` describes on the device's output channels (``params['limits']``:
    name → (low, high, safe)); stalls once for ``params['stall_s']`` to trip the watchdog."""

    name: ClassVar[str] = "device_check"

    def __init__(self, params: Mapping[str, Any], scene: Any = None) -> None:
        super().__init__(params, scene)
        self.limits = {k: tuple(v) for k, v in dict(params["limits"]).items()}
        self.duration = float(params["duration_s"])
        self.stall_s = float(params["stall_s"])
        self.stalled = False

    def reset(self) -> None:
        self.stalled = False

    def step(self, obs: Observation) -> dict[str, float]:
        u = obs.t / self.duration
        lo, hi = PHASES["over_limit"]
        if lo <= u < hi:  # twice the upper limit on every channel
            return {k: 2.0 * high + 1.0 for k, (_low, high, _safe) in self.limits.items()}
        if hi <= u < PHASES["nan"][1]:
            return {k: math.nan for k in self.limits}
        if u >= PHASES["stall_at"] and not self.stalled:
            self.stalled = True
            time.sleep(self.stall_s)  # a plugin that hangs: the loop misses its deadlines
        return {k: safe for k, (_low, _high, safe) in self.limits.items()}


@dataclass(frozen=True)
class DeviceRow:
    name: str
    kind: str  # hardware | simulated
    emulator: bool
    package: str
    detail: str


@dataclass(frozen=True)
class DeviceList:
    devices: tuple[DeviceRow, ...]
    COLUMNS: ClassVar[tuple[str, ...]] = ("name", "kind", "emulator", "package", "detail")

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame([vars(d) for d in self.devices], columns=list(self.COLUMNS))


def list_devices() -> DeviceList:
    """Every device plugin: hardware or simulated, whether it has an emulator, and import problems."""
    from studyctl.plugins.registry import list_plugins, load_plugin  # noqa: PLC0415

    rows = []
    for info in list_plugins("device").plugins:
        if info.status != "ok":
            rows.append(DeviceRow(info.name, "?", False, info.package, info.detail))
            continue
        cls = load_plugin("device", info.name)
        hardware = not getattr(cls, "simulated", True)
        extra = getattr(cls, "EXTRA", "")
        detail = info.detail + (f" (needs {extra})" if extra else "")
        rows.append(DeviceRow(info.name, "hardware" if hardware else "simulated",
                              callable(getattr(cls, "emulate", None)), info.package, detail))
    return DeviceList(tuple(rows))


@dataclass(frozen=True)
class SafetyCheck:
    rule: str
    passed: bool
    detail: str


@dataclass(frozen=True)
class DeviceCheck:
    """What ``studyctl device check`` found."""

    device: str
    emulated: bool
    identity: dict[str, Any]
    limits: dict[str, Any]
    rate_hz: float
    seconds: float
    ticks: int
    achieved_hz: float
    period_jitter_us_p99: float
    late_us_p99: float
    rt: dict[str, Any]
    safety: tuple[SafetyCheck, ...]
    faults: tuple[str, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return all(c.passed for c in self.safety)

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame([vars(c) for c in self.safety], columns=["rule", "passed", "detail"])

    def to_json(self) -> dict[str, Any]:
        out = {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "safety"}
        out["safety"] = [vars(c) for c in self.safety]
        out["ok"] = self.ok
        return out


def _limits_of(device_cls: type, params: Mapping[str, Any]) -> Any:
    import numpy as np  # noqa: PLC0415

    from studyctl.engine.factory import _call_with_supported  # noqa: PLC0415

    return _call_with_supported(device_cls, params=dict(params), scene=None, rng=np.random.default_rng(0)).limits


def _fault_detail(payload: dict[str, Any]) -> str:
    """What a fault event says beyond its rule: its error or sensor faults, else its measured fields (a stale
    sensor's ``age_s`` and ``limit_s``), so the coordinator reads why, not a bare rule name."""
    if "error" in payload or "faults" in payload:
        return str(payload.get("error", payload.get("faults")))
    return ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                     for k, v in payload.items() if k not in ("rule", "channel", "state"))


def check_device(
    name: str, params: Mapping[str, Any] | None = None, *, emulate: bool = False, seconds: float = 3.0,
    rate_hz: float | None = None,
) -> DeviceCheck:
    """Check device ``name`` (with ``params``; its emulator with ``emulate``) for ``seconds`` at ``rate_hz``
    (default: the device's ``rate_hz`` parameter, else 1 kHz for force devices and 50 Hz for others)."""
    from studyctl.devices.emulation import emulated  # noqa: PLC0415
    from studyctl.engine.servo import ServoSpec, run_trial_in_servo_process  # noqa: PLC0415
    from studyctl.plugins.registry import load_plugin  # noqa: PLC0415

    if not (0.5 <= seconds <= 600):
        raise UsageError(f"--seconds must be between 0.5 and 600, got {seconds:g}")
    cls = load_plugin("device", name)
    ref: dict[str, Any] = {"plugin": name, "params": dict(params or {})}
    limits = _limits_of(cls, ref["params"])
    # ``rate_hz`` None means the device's rate; 0 is a value (refused below), not "the default".
    rate = float(rate_hz if rate_hz is not None else
                 ref["params"].get("rate_hz") or (1000.0 if limits.max_force_n is not None else 50.0))
    if not (1.0 <= rate <= 10000.0):
        raise UsageError(f"--rate must be between 1 and 10000 Hz, got {rate:g}")
    ctrl_params = {"limits": {c.name: (c.low, c.high, c.safe) for c in limits.outputs}, "duration_s": seconds,
                   "stall_s": max(0.02, 6.0 / rate)}
    events: list[tuple[float, str, dict[str, Any]]] = []
    written: dict[str, list[float]] = {c.name: [] for c in limits.outputs}
    times: list[float] = []

    def on_sample(t: float, values: Mapping[str, float]) -> None:
        times.append(t)
        for k, lst in written.items():
            if k in values:
                lst.append(values[k])

    with contextlib.ExitStack() as stack:
        if emulate:
            ref = stack.enter_context(emulated(ref))
        spec = ServoSpec(info=TrialInfo("device_check", seconds, rate, "none"), device=name,
                         device_params=ref["params"], controller=f"{__name__}:CheckController",
                         controller_params=ctrl_params)
        result = run_trial_in_servo_process(spec, on_sample=on_sample,
                                            on_event=lambda t, k, p: events.append((t, k, dict(p))))
    kinds = {(k, p.get("rule")) for _t, k, p in events}
    identity = next((p for _t, k, p in events if k == "device_identity"), {})
    checks = []
    over = [(k, max(abs(v) for v in vals)) for k, vals in written.items() if vals]
    bad = [(k, m) for k, m in over if m > max(abs(limits.channel(k).low), abs(limits.channel(k).high)) + 1e-9]
    largest = ", ".join(f"{k}={m:.3g}" for k, m in over)
    checks.append(SafetyCheck("clamp", ("safety", "clamped") in kinds and not bad,
                              f"written beyond limits: {bad}" if bad else
                              f"commands at twice the limit were clamped; largest written: {largest}"))
    finite = all(math.isfinite(v) for vals in written.values() for v in vals)
    checks.append(SafetyCheck("nan", ("safety", "non_finite_command") in kinds and finite,
                              "NaN commands became the safe value" if finite else "a non-finite value was written"))
    tripped = sorted(r for k, r in kinds if k == "device_fault" and r in TIMING_FAULTS)
    checks.append(SafetyCheck("watchdog", bool(tripped),
                              f"a {ctrl_params['stall_s'] * 1000:.0f} ms stall put the device in its safe state "
                              f"({', '.join(tripped)})" if tripped else "the stall was not noticed"))
    other_faults = tuple(sorted({f"{p.get('rule')}: {_fault_detail(p)}" for _t, k, p in events
                                 if k == "device_fault" and p.get("rule") not in TIMING_FAULTS}))
    # pacing before the deliberate stall (tick times as the loop stamped them)
    ts = np.asarray([t for t in times if t < PHASES["stall_at"] * seconds])
    jitter = np.abs(np.diff(ts) - 1.0 / rate) * 1e6 if len(ts) > 2 else np.array([math.nan])
    late = (ts - np.arange(len(ts)) / rate) * 1e6 if len(ts) else np.array([math.nan])
    return DeviceCheck(
        device=name, emulated=emulate, identity=dict(identity),
        limits={"outputs": {c.name: [c.low, c.high, c.safe] for c in limits.outputs}, "max_force_n": limits.max_force_n,
                "sensor_stale_s": limits.sensor_stale_s, "ramp_up_s": limits.ramp_up_s,
                **({"workspace": identity["workspace"]} if "workspace" in identity else {})},
        rate_hz=rate, seconds=seconds, ticks=result.ticks,
        achieved_hz=result.ticks / result.duration_s if result.duration_s > 0 else 0.0,
        period_jitter_us_p99=float(np.percentile(jitter, 99)),
        late_us_p99=float(np.percentile(late, 99)),
        rt=dict(result.rt), safety=tuple(checks), faults=other_faults,
    )


@dataclass(frozen=True)
class Calibration:
    """A stored calibration: its id, the device, when, the parameters it sets and how they were measured."""

    id: int
    device: str
    created_at: str
    emulated: bool
    params: dict[str, Any]
    detail: dict[str, Any]

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame([{"id": self.id, "device": self.device, "created_at": self.created_at,
                              "emulated": self.emulated, "params": self.params}])


def calibrate_device(
    store: Any, study: Any, name: str, params: Mapping[str, Any] | None = None, *, emulate: bool = False,
    seconds: float = 2.0,
) -> Calibration:
    """Zero or calibrate device ``name`` (its ``calibrate(seconds)``) and store the result in the study database.

    Later sessions of the study on that device use the newest calibration (real hardware for real sessions, an
    emulator's for rehearsals) and record its id in a ``device_calibration`` event."""
    from studyctl.devices.emulation import emulated  # noqa: PLC0415
    from studyctl.engine.factory import _call_with_supported  # noqa: PLC0415
    from studyctl.plugins.registry import load_plugin  # noqa: PLC0415
    from studyctl.store.models import DeviceCalibration  # noqa: PLC0415

    if not (0.1 <= seconds <= 120):
        raise UsageError(f"--seconds must be between 0.1 and 120, got {seconds:g}")
    cls = load_plugin("device", name)
    if not callable(getattr(cls, "calibrate", None)):
        raise UsageError(f"device {name} needs no calibration (it has no zero or calibration procedure)")
    with contextlib.ExitStack() as stack:
        ref: dict[str, Any] = {"plugin": name, "params": dict(params or {})}
        if emulate:
            ref = stack.enter_context(emulated(ref))
        device = _call_with_supported(cls, params=dict(ref["params"]), scene=None, rng=np.random.default_rng(0))
        device.open()
        try:
            identity = dict(device.identity()) if callable(getattr(device, "identity", None)) else {}
            result = device.calibrate(seconds)
        finally:
            device.close()
    detail = {**dict(result.get("detail") or {}), "identity": identity, "emulated": emulate, "seconds": seconds}
    with store.in_transaction() as tx:
        row = DeviceCalibration(study_id=study.id, device=name, params=dict(result["params"]), detail=detail)
        tx.add(row)
        tx.flush()
        cid, created = int(row.id), row.created_at
    return Calibration(cid, name, created.isoformat() if created else "", emulate, dict(result["params"]), detail)


def latest_calibration(store: Any, study_id: int, device: str, *, emulated: bool) -> Calibration | None:
    """The newest calibration of ``device`` in the study measured on real hardware (or, ``emulated``, an emulator)."""
    from sqlalchemy import select  # noqa: PLC0415

    from studyctl.store.models import DeviceCalibration  # noqa: PLC0415

    with store.reading() as s:
        rows = s.scalars(select(DeviceCalibration).where(DeviceCalibration.study_id == study_id,
                                                        DeviceCalibration.device == device)
                         .order_by(DeviceCalibration.id.desc())).all()
        for r in rows:
            if bool((r.detail or {}).get("emulated", False)) == emulated:
                return Calibration(int(r.id), r.device, r.created_at.isoformat() if r.created_at else "", emulated,
                                   dict(r.params or {}), dict(r.detail or {}))
    return None
