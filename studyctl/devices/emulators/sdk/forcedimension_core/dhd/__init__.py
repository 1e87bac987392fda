"""``forcedimension_core.dhd`` on studyctl's emulator (see the package docstring)."""

from __future__ import annotations

import os
import time

from studyctl.devices.emulators import shm_device as _emu

_state: dict = {"shm": None, "s": None, "id": -1, "err": "", "seen": (-1.0, 0.0)}


def _fail(msg: str) -> int:
    _state["err"] = msg
    return -1


def _live():
    """The shared state if the device is open and answering, else None (error set)."""
    s = _state["s"]
    if s is None:
        _fail("no device open")
        return None
    if not _emu.answering(_state):
        _fail("communication error: the device does not answer (timeout)")
        return None
    return s


def errorGetLastStr() -> str:  # noqa: N802 - the SDK's names
    return _state["err"] or "no error"


def getDeviceCount() -> int:  # noqa: N802
    return 1 if os.environ.get("STUDYCTL_FD_EMULATOR") else 0


def open() -> int:  # noqa: A001 - the SDK's name
    return openID(0)


def openID(index: int) -> int:  # noqa: N802
    name = os.environ.get("STUDYCTL_FD_EMULATOR")
    if not name or index != 0:
        return _fail("no device found")
    try:
        shm, s = _emu.attach(name)
    except FileNotFoundError:
        return _fail("no device found")
    if s[_emu.OPENED] > 0:
        shm.close()
        return _fail("device busy: opened by another process")
    s[_emu.OPENED] = float(os.getpid())
    _state.update(shm=shm, s=s, id=0, seen=(-1.0, time.monotonic()))
    return 0


def close(ID: int = -1) -> int:  # noqa: N803
    s, shm = _state["s"], _state["shm"]
    if s is None:
        return _fail("no device open")
    s[_emu.ENABLED] = 0.0
    s[_emu.CMD:_emu.CMD + 3] = 0.0
    s[_emu.OPENED] = 0.0
    _state.update(shm=None, s=None, id=-1)
    shm.close()
    return 0


def getSystemName(ID: int = -1) -> str | None:  # noqa: N802, N803
    s = _state["s"]
    if s is None:
        return None
    return {1: "omega.6", 2: "Touch"}.get(int(s[_emu.MODEL]), "unknown")


def getSerialNumber(ID: int = -1) -> int:  # noqa: N802, N803
    return 4242 if _state["s"] is not None else _fail("no device open")


def getComFrequency(ID: int = -1) -> float:  # noqa: N802, N803
    s = _live()
    return float(s[_emu.RATE]) / 1000.0 if s is not None else -1.0  # kHz, as the SDK


def enableForce(enable: bool, ID: int = -1) -> int:  # noqa: N802, N803
    s = _live()
    if s is None:
        return -1
    s[_emu.ENABLED] = 1.0 if enable else 0.0
    return 0


def setMaxForce(limit: float, ID: int = -1) -> int:  # noqa: N802, N803
    s = _live()
    if s is None:
        return -1
    s[_emu.MAX_FORCE] = float(limit) if limit >= 0 else float(s[_emu.MAX_NOMINAL])
    return 0


def getMaxForce(ID: int = -1) -> float:  # noqa: N802, N803
    s = _live()
    return float(s[_emu.MAX_FORCE]) if s is not None else -1.0


def _vec(out, base: int) -> int:
    s = _live()
    if s is None:
        return -1
    out[0], out[1], out[2] = float(s[base]), float(s[base + 1]), float(s[base + 2])
    return 0


def getPosition(out, ID: int = -1) -> int:  # noqa: N802, N803
    return _vec(out, _emu.POS)


def getLinearVelocity(out, ID: int = -1) -> int:  # noqa: N802, N803
    return _vec(out, _emu.VEL)


def getForce(out, ID: int = -1) -> int:  # noqa: N802, N803
    return _vec(out, _emu.APPLIED)


def getOrientationFrame(out, ID: int = -1) -> int:  # noqa: N802, N803
    s = _live()
    if s is None:
        return -1
    r = s[_emu.ROT:_emu.ROT + 9]
    for i in range(3):
        for j in range(3):
            out[i][j] = float(r[3 * i + j])
    return 0


def getButton(index: int, ID: int = -1) -> int:  # noqa: N802, N803
    s = _live()
    if s is None:
        return -1
    return 1 if index == 0 and s[_emu.BUTTON] > 0 else 0


def setForce(f, ID: int = -1) -> int:  # noqa: N802, N803
    s = _live()
    if s is None:
        return -1
    s[_emu.CMD], s[_emu.CMD + 1], s[_emu.CMD + 2] = float(f[0]), float(f[1]), float(f[2])
    s[_emu.CMD_SEQ] += 1.0
    return 2 if s[_emu.SATURATED] > 0 else 0  # MOTOR_SATURATED, as the SDK


from . import expert  # noqa: E402,F401 - the SDK exposes dhd.expert
