"""``pyOpenHaptics.hd`` on studyctl's emulator (see the package docstring)."""

from __future__ import annotations

import os
import time

from studyctl.devices.emulators import shm_device as _emu

from .hd_define import *  # noqa: F403
from .hd_define import HD_BAD_HANDLE, HD_COMM_ERROR, HD_SUCCESS
from .hdu_matrix import hduMatrix, hduVector3Dd

_state: dict = {"shm": None, "s": None, "error": HD_SUCCESS, "seen": (-1.0, 0.0), "running": False}


def _live():
    s = _state["s"]
    if s is None:
        _state["error"] = HD_BAD_HANDLE
        return None
    if not _emu.answering(_state):
        _state["error"] = HD_COMM_ERROR  # the device stopped answering
        return None
    return s


def init_device(name: str = "Default Device") -> int:
    emulator = os.environ.get("STUDYCTL_HD_EMULATOR")
    try:
        shm, s = _emu.attach(emulator) if emulator else (None, None)
    except FileNotFoundError:
        shm, s = None, None
    if s is None:
        print("Unable to initialize the device. Check the connection!")  # as the wrapper does
        return None
    if s[_emu.OPENED] > 0:
        shm.close()
        _state["error"] = HD_BAD_HANDLE
        print("Unable to initialize the device. Check the connection!")
        return None
    s[_emu.OPENED] = float(os.getpid())
    _state.update(shm=shm, s=s, error=HD_SUCCESS, seen=(-1.0, time.monotonic()))
    return 1


def get_buttons() -> int:
    s = _live()
    return int(s[_emu.BUTTON]) if s is not None else 0


def get_transform():
    m = hduMatrix()
    s = _live()
    for i in range(4):
        m[i][i] = 1.0
    if s is not None:
        for j in range(3):
            m[3][j] = 1000.0 * float(s[_emu.POS + j])  # OpenHaptics reports mm, translation in the last row
    return m


def _get_velocity():
    v = hduVector3Dd()
    s = _live()
    if s is not None:
        for j in range(3):
            v[j] = 1000.0 * float(s[_emu.VEL + j])  # mm/s
    return v


def get_error() -> bool:
    return _state["error"] != HD_SUCCESS


def set_force(feedback) -> None:
    s = _live()
    if s is None:
        return
    s[_emu.CMD], s[_emu.CMD + 1], s[_emu.CMD + 2] = (float(feedback[0]), float(feedback[1]), float(feedback[2]))
    s[_emu.CMD_SEQ] += 1.0


def close_device(id: int):  # noqa: A002 - the wrapper's name
    s, shm = _state["s"], _state["shm"]
    if s is None:
        return
    s[_emu.ENABLED] = 0.0
    s[_emu.CMD:_emu.CMD + 3] = 0.0
    s[_emu.OPENED] = 0.0
    _state.update(s=None, shm=None)
    shm.close()


def get_current_device() -> int:
    return 1 if _state["s"] is not None else HD_BAD_HANDLE


def make_current_device(id: int) -> None:  # noqa: A002
    return None


def start_scheduler() -> None:
    _state["running"] = True


def stop_scheduler() -> None:
    _state["running"] = False


def enable_force() -> None:
    s = _live()
    if s is not None:
        s[_emu.ENABLED] = 1.0
        # OpenHaptics' HD_FORCE_RAMPING-free start; the device's own watchdog (HD servo loop) is ~ a few ms
        s[_emu.WATCHDOG] = 80.0


def begin_frame(id: int) -> None:  # noqa: A002
    return None


def end_frame(id: int) -> None:  # noqa: A002
    return None


def get_model() -> str:
    return "Touch" if _state["s"] is not None else ""


def get_vendor() -> str:
    return "3D Systems" if _state["s"] is not None else ""
