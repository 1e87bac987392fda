"""Stand-in for ``pyOpenHaptics`` (the OpenHaptics HDAPI wrapper, PyPI ``pyopenhaptics``) on studyctl's device
emulator: the same modules (``hd``, ``hd_callback``, ``hd_device``, ``hd_define``, ``hdu_matrix``), function names
and signatures, driving the emulator named by ``STUDYCTL_HD_EMULATOR`` instead of libHD. Only what studyctl's
Touch adapter uses is provided."""

from .hd import *  # noqa: F403 - the real package re-exports hd

EMULATED = True
