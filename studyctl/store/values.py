"""What the store accepts as a value: short texts, choices, seeds, rows that must exist (one `Error:` line each).

Used by the repository (:mod:`studyctl.store.repository`) and its session records
(:mod:`studyctl.store.session_records`), and by the workspace for a study's name.
"""

from __future__ import annotations

import hashlib
from typing import Any, TypeVar

from sqlalchemy.orm import Session as OrmSession

from studyctl.errors import NotFoundError, UsageError
from studyctl.store.audit import canonical_json
from studyctl.store.models import Participant, Session, Study, Trial

MAX_TEXT = 200
_SEED_LIMIT = 2**63
StoredRow = TypeVar("StoredRow", Study, Participant, Session, Trial)


def check_text(value: Any, what: str, *, max_len: int = MAX_TEXT, allow_none: bool = False) -> str | None:
    """Validate a short text stored verbatim (codes, names): non-empty, ≤ ``max_len``, no NUL."""
    if value is None and allow_none:
        return None
    if not isinstance(value, str):
        raise UsageError(f"{what} must be text, got {type(value).__name__} {value!r}")
    if value == "":
        raise UsageError(f"{what} must not be empty")
    if len(value) > max_len:
        raise UsageError(f"{what} {value[:40]!r}… is {len(value)} characters long; at most {max_len} are allowed")
    if "\x00" in value:
        raise UsageError(f"{what} {value!r} contains a NUL character (\\x00), which PostgreSQL cannot store; "
                         "remove it")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise UsageError(f"{what} {value!r} is not valid Unicode text (a lone surrogate); re-type it") from None
    return value


def require(s: OrmSession, model: type[StoredRow], key: int) -> StoredRow:
    """``s.get(model, key)``, or :class:`NotFoundError` ``no <table> with id <key>``."""
    row = s.get(model, key)
    if row is None:
        raise NotFoundError(f"no {model.__tablename__} with id {key}")
    return row


def check_choice(value: str, allowed: tuple[str, ...], what: str) -> str:
    if value not in allowed:
        raise UsageError(f"{what} {value!r} is not allowed; use one of {', '.join(allowed)}")
    return value


def check_seed(seed: int | None, what: str) -> int | None:
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, int) or not (0 <= seed < _SEED_LIMIT):
        raise UsageError(f"{what} must be an integer in [0, 2**63), got {seed!r}")
    return seed


def schedule_sha256(schedule: Any) -> str:
    """sha256 of the canonical JSON of a schedule (stored to detect later edits of the plan)."""
    return hashlib.sha256(canonical_json(schedule).encode("utf-8")).hexdigest()


__all__ = ["MAX_TEXT", "check_choice", "check_seed", "check_text", "require", "schedule_sha256"]
