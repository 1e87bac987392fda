"""studyctl: run human-subject studies of haptic feedback from protocol to published statistics."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("studyctl")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
