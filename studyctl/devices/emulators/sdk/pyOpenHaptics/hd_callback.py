"""``pyOpenHaptics.hd_callback`` on studyctl's emulator: the servo scheduler is a thread at the device's rate."""

from __future__ import annotations

import contextlib
import functools
import os
import threading
import time

from studyctl.devices.emulators import shm_device as _emu

from . import hd
from .hd_define import HD_CALLBACK_CONTINUE, HD_CALLBACK_DONE


def hd_callback(input_function):
    @functools.wraps(input_function)
    def _callback(pUserData=None):  # noqa: N803
        hd.begin_frame(hd.get_current_device())
        input_function()
        hd.end_frame(hd.get_current_device())
        if hd.get_error():
            return HD_CALLBACK_DONE  # as the wrapper: any HD error stops the servo callback
        return HD_CALLBACK_CONTINUE

    return _callback


def _servo(callback) -> None:
    # OpenHaptics runs its servo thread at the highest scheduling priority it can get; so does this one
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(80))
    s = hd._state["s"]
    period = 1.0 / float(s[_emu.RATE]) if s is not None and s[_emu.RATE] > 0 else 1e-3
    next_t = time.perf_counter()
    while hd._state["running"] and hd._state["s"] is not None:
        if callback() == HD_CALLBACK_DONE:
            return
        next_t += period
        delay = next_t - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        else:
            next_t = time.perf_counter()


def hdAsyncSheduler(callback):  # noqa: N802 - the wrapper's (misspelt) name
    threading.Thread(target=_servo, args=(callback,), name="hd-servo", daemon=True).start()


def hdSyncSheduler(callback):  # noqa: N802
    callback()
