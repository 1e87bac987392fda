"""One problem found in a protocol file, and how it is worded.

Every problem names the file, line and column, the key path, what was found and what is allowed, so
that a coordinator can fix the file without reading studyctl's source::

    needle.yaml:12:5: trial.time_limit_s: time limit must be positive: found 0, allowed a number > 0
    needle.yaml:3:1: studdy: unknown key: found 'studdy', allowed one of 'conditions', 'study'; did you mean 'study'?
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

PathKey = str | int
KeyPath = tuple[PathKey, ...]


@dataclass(frozen=True)
class Mark:
    """A 1-based line and column in a source file."""

    line: int
    column: int


def format_path(path: Sequence[PathKey]) -> str:
    """Render a key path as ``conditions[2].params.k_p`` (``<root>`` for the empty path)."""
    out = ""
    for key in path:
        if isinstance(key, int):
            out += f"[{key}]"
        else:
            out += f".{key}" if out else str(key)
    return out or "<root>"


def show(value: object) -> str:
    """A short, quoted rendering of a found value for messages."""
    if isinstance(value, dict):
        return "a mapping" if value else "an empty mapping"
    if isinstance(value, list):
        if not value:
            return "an empty list"
        if all(isinstance(v, (str, int, float)) and not isinstance(v, bool) for v in value):
            text = "[" + ", ".join(str(v) for v in value) + "]"
            if len(text) <= 60:
                return text
        return "a list"
    if value is None:
        return "null"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def one_of(choices: Iterable[object]) -> str:
    """``one of 'a', 'b', 'c'`` for an allowed-values clause."""
    items = [repr(c) for c in choices]
    if not items:
        return "nothing"
    return items[0] if len(items) == 1 else "one of " + ", ".join(items)


@dataclass(frozen=True)
class Problem:
    """One error in a protocol file, with everything the message needs."""

    file: str
    mark: Mark
    path: KeyPath
    what: str
    found: str
    allowed: str
    suggestion: str | None = None
    #: What kind of YAML-level problem (``yamlmarks.SYNTAX`` …), for callers that word their own message;
    #: empty for problems found after loading.
    kind: str = ""

    def __str__(self) -> str:
        text = (
            f"{self.file}:{self.mark.line}:{self.mark.column}: {format_path(self.path)}: {self.what}: "
            f"found {self.found}, allowed {self.allowed}"
        )
        if self.suggestion is not None:
            text += f"; did you mean {self.suggestion!r}?"
        return text

    @property
    def sort_key(self) -> tuple[int, int, str]:
        return (self.mark.line, self.mark.column, str(self))
