"""Emulators of hardware devices and of their vendors' Python APIs, for tests and rehearsals.

``sdk/`` holds stand-ins for vendor packages with the same module, function names and signatures as the real
ones (read from their public sources, not copied); each talks to an emulator process that models the device's
timing, workspace and force limits. A device adapter puts ``sdk/`` first on ``sys.path`` only when it is told to
emulate (its ``emulator`` parameter), so the real package is used otherwise.
"""

import contextlib
import os
from pathlib import Path

SDK_DIR = str(Path(__file__).parent / "sdk")
FIRMWARE_PRIORITY = 70  # SCHED_FIFO, below the servo loop's 80 (studyctl.engine.realtime)


def firmware_priority() -> None:
    """Run an emulator's loop above normal processes when permitted, else as nicely as allowed: a device's firmware
    does not wait for the host's scheduler (a board emulator starved by a loaded machine sent its sensor packets
    > 0.1 s late, a stale-sensor fault no real board would cause)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0),
                              os.sched_param(FIRMWARE_PRIORITY))
    except (OSError, AttributeError):
        with contextlib.suppress(OSError):
            os.nice(-5)
