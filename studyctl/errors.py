"""The one exception tree of studyctl.

Every error a user can cause is a :class:`StudyctlError`. Subclasses also inherit the matching
built-in (``ValueError``, ``LookupError`` …) so library callers can catch either. The CLI turns any
``StudyctlError`` into one ``Error: …`` line on stderr and a non-zero exit code; messages therefore
name the file, line, field or value, what was allowed, and how to fix it.
"""

from __future__ import annotations


class StudyctlError(Exception):
    """Base class of every error studyctl raises on purpose."""

    exit_code: int = 1


class UsageError(StudyctlError, ValueError):
    """A command-line or API argument is invalid."""

    exit_code = 2


class ConfigError(StudyctlError, ValueError):
    """A configuration value (environment variable, workspace file) is invalid."""


class ProtocolError(StudyctlError, ValueError):
    """A protocol or analysis-plan file is invalid; ``problems`` lists every problem found."""

    def __init__(self, message: str, problems: list[str] | None = None) -> None:
        super().__init__(message)
        self.problems: list[str] = list(problems or [message])


class NotFoundError(StudyctlError, LookupError):
    """A named thing (study, participant, session, plugin, file) does not exist."""


class StoreError(StudyctlError, RuntimeError):
    """The study database cannot be opened, read or written."""


class SchemaVersionError(StoreError):
    """The database schema revision is newer than this studyctl, or unknown to it."""


class IntegrityError(StoreError):
    """Stored data fails a consistency check (audit hash chain, schedule hash, sample counts)."""


class SessionError(StudyctlError, RuntimeError):
    """A session cannot start, continue or resume in its current state."""


class SessionInterrupted(SessionError):
    """A session stopped on purpose (Ctrl-C, coordinator stop) in a resumable state."""

    exit_code = 130


class PluginError(StudyctlError, ImportError):
    """A plugin is unknown or failed to load."""


class DeviceError(StudyctlError, RuntimeError):
    """A device cannot be opened, read or written."""


class SafetyFault(DeviceError):
    """The safety layer put a device in its safe state (watchdog, stale sensor, invalid command)."""


class ModelParameterError(StudyctlError, ValueError):
    """A model or controller parameter is out of its allowed range."""


class PopulationError(StudyctlError, ValueError):
    """A population or targets file is invalid, or does not fit the protocol it is used with."""


class StatsInputError(StudyctlError, ValueError):
    """Input to a statistical function is invalid (empty sample, bad confidence, successes > n …)."""


class AnalysisError(StudyctlError, ValueError):
    """An analysis plan cannot be executed on the given data."""


__all__ = [
    "AnalysisError",
    "ConfigError",
    "DeviceError",
    "IntegrityError",
    "ModelParameterError",
    "NotFoundError",
    "PluginError",
    "PopulationError",
    "ProtocolError",
    "SafetyFault",
    "SchemaVersionError",
    "SessionError",
    "SessionInterrupted",
    "StatsInputError",
    "StoreError",
    "StudyctlError",
    "UsageError",
]
