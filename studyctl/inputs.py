"""Reading text and JSON a user (or a browser) hands us, within bounds.

Every file studyctl reads as text (protocols, plans, answer scripts, populations, stiffness-map manifests)
goes through :func:`read_text`: a size limit before reading it whole and a clear error for a file that is
not UTF-8 text (e.g. ``--input`` pointed at a binary file). JSON from a request body or a file goes through
:func:`loads_json`: a nesting limit checked on the raw text first, because Python's ``json`` recurses once
per level and a 60 KB ``[[[[…`` body otherwise ends in ``RecursionError``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from studyctl.errors import UsageError

MAX_TEXT_BYTES = 2_000_000
MAX_JSON_DEPTH = 64


def read_text(path: str | os.PathLike[str], what: str, *, max_bytes: int = MAX_TEXT_BYTES,
              error: type[Exception] = UsageError) -> str:
    """The UTF-8 text of ``path``; ``error`` naming the file and what is wrong otherwise."""
    file = Path(path)
    try:
        size = file.stat().st_size
        if size > max_bytes:
            raise error(f"{file}: {what} is {size:,} bytes; at most {max_bytes:,} are read (is this the right file?)")
        raw = file.read_bytes()
    except IsADirectoryError:
        raise error(f"{file} is a folder; pass the {what} file itself") from None
    except FileNotFoundError:
        raise error(f"{file} does not exist; pass an existing {what} file") from None
    except OSError as exc:
        raise error(f"cannot read {what} {file}: {exc.strerror or exc}") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise error(f"{file}:{line}: {what} is not UTF-8 text: byte {raw[exc.start]:#04x} at offset {exc.start}; "
                    f"pass a UTF-8 text file (YAML or JSON), not a binary one") from None


def json_depth(text: str | bytes, limit: int = MAX_JSON_DEPTH) -> int:
    """Nesting depth of JSON text (stops counting at ``limit + 1``); strings are skipped, so it is exact for
    valid JSON and harmless for invalid JSON (the parser then reports it)."""
    if isinstance(text, bytes):
        text = text.decode("utf-8", errors="replace")
    depth = best = 0
    in_string = escaped = False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            if depth > best:
                best = depth
                if best > limit:
                    return best
        elif ch in "]}":
            depth -= 1
    return best


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a finite number; JSON numbers must be finite")


def loads_json(text: str | bytes, *, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """``json.loads`` with a nesting limit; ValueError (never RecursionError) for bad or too deep JSON."""
    if json_depth(text, max_depth) > max_depth:
        raise ValueError(f"JSON nested more than {max_depth} levels deep")
    try:
        return json.loads(text, parse_constant=_no_constant)
    except RecursionError:  # pragma: no cover - the depth check comes first
        raise ValueError(f"JSON nested more than {max_depth} levels deep") from None


def xy_pair(tokens: Sequence[str], *, wrong_count: str, not_numbers: str,
            error: type[Exception] = UsageError) -> tuple[float, float]:
    """A typed position (x and y in mm) from its tokens: ``error(wrong_count)`` unless there are two,
    ``error(not_numbers)`` unless both are numbers. Range checks are the caller's (its bounds, its message)."""
    if len(tokens) != 2:
        raise error(wrong_count)
    try:
        return float(tokens[0]), float(tokens[1])
    except ValueError:
        raise error(not_numbers) from None


__all__ = ["MAX_JSON_DEPTH", "MAX_TEXT_BYTES", "json_depth", "loads_json", "read_text", "xy_pair"]
