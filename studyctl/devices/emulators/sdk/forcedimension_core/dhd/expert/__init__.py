"""``forcedimension_core.dhd.expert`` on studyctl's emulator: the firmware watchdog."""

from __future__ import annotations

from studyctl.devices.emulators import shm_device as _emu


def setWatchdog(duration: int, ID: int = -1) -> int:  # noqa: N802, N803
    from forcedimension_core import dhd  # noqa: PLC0415

    s = dhd._live()
    if s is None:
        return -1
    if not 0 <= int(duration) <= 255:  # a C unsigned char in the SDK
        return dhd._fail(f"watchdog duration {duration} outside 0..255")
    s[_emu.WATCHDOG] = float(int(duration))
    return 0


def getWatchdog(ID: int = -1) -> int:  # noqa: N802, N803
    from forcedimension_core import dhd  # noqa: PLC0415

    s = dhd._live()
    return int(s[_emu.WATCHDOG]) if s is not None else -1
