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


class UnknownKeyError(NotFoundError, KeyError):
    """A lookup by id or name found nothing where the caller may expect a mapping's ``KeyError``."""

    def __str__(self) -> str:  # KeyError quotes its message; this one is a sentence
        return str(self.args[0]) if self.args else ""


class ValueTypeError(StudyctlError, TypeError):
    """A value of a type studyctl cannot take (the audit log and the view's messages take JSON values).

    Not a ``ValueError``: code that turns a ``ValueError`` of ``json.dumps`` (NaN) into its own message must not
    catch this one."""

    exit_code = 2


class NotSupportedError(StudyctlError, NotImplementedError):
    """A plugin lacks an optional capability the study asked of it (a participant that cannot answer items)."""


class InvalidAnswer(StudyctlError, ValueError):
    """A participant's typed answer is not allowed (off the scale, off the grid); the prompt names what is
    allowed and asks again."""


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


class DatagramError(DeviceError, ValueError):
    """A driver-board datagram is malformed (short, bad magic or version, unknown type, CRC mismatch)."""


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


class BenchmarkError(StudyctlError, RuntimeError):
    """A benchmark's own check of what it measured failed, so its figures would be wrong."""


__all__ = [
    "AnalysisError",
    "BenchmarkError",
    "ConfigError",
    "DatagramError",
    "DeviceError",
    "IntegrityError",
    "InvalidAnswer",
    "ModelParameterError",
    "NotFoundError",
    "NotSupportedError",
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
    "UnknownKeyError",
    "UsageError",
    "ValueTypeError",
]
