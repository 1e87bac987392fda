"""The contract every device plugin (built-in or third-party) must keep, as one checkable function.

:func:`contract_problems` builds the device by its entry-point name (hardware through its emulator, which the
plugin must provide as ``emulate(params, hang_after_s=None)``), and returns what it found wrong; an empty list means
the plugin keeps the contract. ``tests/devices/test_contract.py`` runs it for every installed device plugin, so a
third-party plugin is held to it by installing it next to studyctl and running that test (or calling this).

The contract:

1. the class names itself (``name`` = its entry-point name), says ``simulated`` (bool) and builds from
   ``(params=, scene=, rng=)``; unknown parameters are a :class:`~studyctl.errors.StudyctlError` naming the device;
2. ``limits``: each output channel with low ≤ safe ≤ high (hardware: at least one); ``max_force_n`` None or > 0;
   ``sensor_stale_s`` > 0;
3. hardware: ``read``/``write`` before ``open`` raise :class:`~studyctl.errors.DeviceError`;
4. after ``open``: ``read(t)`` gives an :class:`Observation` at ``t`` of named finite floats; ``write`` of the safe
   command and ``feedback()`` work; a hardware sample is fresh at the device's own pace (age ≤ ``sensor_stale_s``
   over ``ticks`` reads at 1 kHz); ``close()`` may be called twice;
5. hardware: when the device stops answering, a trial ends by the safety layer's watchdog (``device_fault``, ended
   by ``fault``) within a few seconds: never a hang.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from studyctl.errors import DeviceError, StudyctlError
from studyctl.plugins.interfaces import DeviceLimits, IdleParticipant, Observation, TrialInfo
from studyctl.plugins.registry import load_plugin

SceneFactory = Callable[[], Any]


def _build(cls: type, params: Mapping[str, Any], scene: Any) -> Any:
    from studyctl.engine.factory import _call_with_supported  # noqa: PLC0415

    return _call_with_supported(cls, params=dict(params), scene=scene, rng=np.random.default_rng(0))


def contract_problems(name: str, params: Mapping[str, Any] | None = None, *, scene: SceneFactory | None = None,
                      ticks: int = 300, check_hang: bool = True) -> list[str]:
    """What device plugin ``name`` gets wrong (empty: it keeps the contract). ``scene`` builds the scene a simulated
    device needs; hardware runs on its emulator."""
    problems: list[str] = []
    cls = load_plugin("device", name)
    if getattr(cls, "name", None) != name:
        problems.append(f"class attribute name is {getattr(cls, 'name', None)!r}, not its entry-point name {name!r}")
    simulated = getattr(cls, "simulated", None)
    if not isinstance(simulated, bool):
        problems.append("class attribute simulated must be True or False")
        return problems
    try:
        _build(cls, {**dict(params or {}), "no_such_parameter_xyz": 1}, scene() if scene else None)
        problems.append("an unknown parameter was accepted (must raise a StudyctlError naming the device)")
    except StudyctlError as exc:
        if name not in str(exc):
            problems.append(f"the unknown-parameter error does not name the device: {exc}")
    except Exception as exc:  # noqa: BLE001 - the contract reports it
        problems.append(f"an unknown parameter raised {type(exc).__name__}, not a StudyctlError: {exc}")
    if not simulated and not callable(getattr(cls, "emulate", None)):
        return [*problems, "a hardware device must provide emulate(params) (its emulator, for tests and rehearsals)"]
    with contextlib.ExitStack() as stack:
        p = dict(params or {})
        if not simulated:
            p = stack.enter_context(cls.emulate(p))
        device = _build(cls, p, scene() if scene else None)
        problems += _limits_problems(getattr(device, "limits", None), hardware=not simulated)
        if problems and getattr(device, "limits", None) is None:
            return problems
        if not simulated:
            for op, call in (("read", lambda: device.read(0.0)), ("write", lambda: device.write({}))):
                try:
                    call()
                    problems.append(f"{op} before open() did not raise DeviceError")
                except DeviceError:
                    pass
                except Exception as exc:  # noqa: BLE001
                    problems.append(f"{op} before open() raised {type(exc).__name__}, not DeviceError")
        device.open()
        try:
            problems += _io_problems(device, simulated, ticks)
        finally:
            device.close()
            try:
                device.close()
            except Exception as exc:  # noqa: BLE001
                problems.append(f"close() twice raised {type(exc).__name__}: {exc}")
    if not simulated and check_hang:
        problems += _hang_problems(cls, dict(params or {}))
    return problems


def _limits_problems(limits: Any, hardware: bool) -> list[str]:
    if not isinstance(limits, DeviceLimits):
        return ["the instance has no DeviceLimits in .limits"]
    out = []
    if hardware and not limits.outputs:
        out.append("limits.outputs is empty: the safety layer has nothing to bound")
    for c in limits.outputs:
        if not (c.low <= c.safe <= c.high):
            out.append(f"channel {c.name}: safe value {c.safe} is not within [{c.low}, {c.high}]")
    if limits.max_force_n is not None and not limits.max_force_n > 0:
        out.append(f"max_force_n {limits.max_force_n} must be None or > 0")
    if not limits.sensor_stale_s > 0:
        out.append(f"sensor_stale_s {limits.sensor_stale_s} must be > 0")
    return out


def _io_problems(device: Any, simulated: bool, ticks: int) -> list[str]:
    out = []
    safe = device.limits.safe_command()
    t0 = time.perf_counter()
    worst_age = 0.0
    for i in range(ticks):
        t = time.perf_counter() - t0
        obs = device.read(t)
        if i == 0:
            if not isinstance(obs, Observation) or obs.t != t:
                return [f"read(t) must return an Observation at t; got {obs!r}"]
            bad = [k for k, v in obs.values.items() if not isinstance(k, str) or not isinstance(v, float)]
            if bad:
                out.append(f"channels that are not str -> float: {bad}")
            nonfinite = [k for k, v in obs.values.items() if isinstance(v, float) and not math.isfinite(v)]
            if nonfinite and not obs.faults:
                out.append(f"non-finite channels without a fault: {nonfinite}")
        if obs.sample_t is not None:
            worst_age = max(worst_age, t - obs.sample_t)
        device.write(safe)
        fb = device.feedback()
        if not isinstance(fb, Mapping):
            out.append("feedback() must return a mapping")
            break
        time.sleep(max(0.0, t0 + (i + 1) * 1e-3 - time.perf_counter()))
    if not simulated and worst_age > device.limits.sensor_stale_s:
        out.append(f"a sample was {worst_age * 1000:.1f} ms old, beyond sensor_stale_s "
                   f"{device.limits.sensor_stale_s * 1000:.1f} ms (the device or its emulator is too slow)")
    return out


def _hang_problems(cls: type, params: dict[str, Any], hang_after_s: float = 0.5, limit_s: float = 5.0) -> list[str]:
    from studyctl.engine.realtime import TimedClock  # noqa: PLC0415
    from studyctl.engine.trial_loop import run_trial  # noqa: PLC0415

    events: list[tuple[str, dict]] = []
    with cls.emulate(params, hang_after_s=hang_after_s) as p:
        device = _build(cls, p, None)
        device.open()
        started = time.monotonic()
        try:
            out = run_trial(info=TrialInfo("contract", 30.0, 250.0, "none"), controller=None, device=device,
                            participant=IdleParticipant(), clock=TimedClock(capacity=10_000),
                            rng=np.random.default_rng(0),
                            on_event=lambda t, k, pl: events.append((k, dict(pl))))
        except DeviceError:
            return []  # the device said so at once: not a hang
        finally:
            device.close()
        took = time.monotonic() - started
    problems = []
    if out.ended_by != "fault":
        problems.append(f"after the emulator stopped answering the trial ended by {out.ended_by!r}, not 'fault'")
    if not any(k == "device_fault" for k, _ in events):
        problems.append("no device_fault event after the emulator stopped answering")
    if took > hang_after_s + limit_s:
        problems.append(f"the trial took {took:.1f} s to stop after the emulator stopped answering")
    return problems
