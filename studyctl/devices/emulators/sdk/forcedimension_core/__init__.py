"""Stand-in for the ``forcedimension_core`` package (Force Dimension SDK bindings) that drives studyctl's device
emulator instead of libdhd: same module layout (``forcedimension_core.dhd``, ``forcedimension_core.dhd.expert``),
function names, signatures and return conventions (0 / device ID on success, -1 on error with the reason in
``dhd.errorGetLastStr()``). Only the functions studyctl's adapter and device tools use are provided.

The emulator to drive is named by the environment variable ``STUDYCTL_FD_EMULATOR`` (the shared block printed by
``python -m studyctl.devices.emulators.shm_device``).
"""

__version__ = "1.0.0+studyctl.emulator"
EMULATED = True
