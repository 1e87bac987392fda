"""Names: the "did you mean …?" hint for a misspelt name (one matcher for protocols, plans, plugins and CLI),
and :func:`named`, the one lookup of an item by its id or name.

``difflib`` closeness with its usual cutoff (0.6), the single best match only, compared case-insensitively
(``studdy`` and ``Study`` both find ``study``; ``bl`` in an analysis plan finds the condition ``BL``).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from typing import TypeVar

from studyctl.errors import UnknownKeyError

T = TypeVar("T")


def nearest(word: object, choices: Iterable[object], *, ignore_case: bool = True) -> str | None:
    """The valid choice nearest to a misspelt ``word``, or None when nothing is close.

    Parameters
    ----------
    word
        What the user wrote (compared as text).
    choices
        The valid names (compared as text).
    ignore_case
        Compare lower-cased (default); the choice is returned as written. False: exact case only.

    Returns
    -------
    str or None
        The closest choice (difflib ratio ≥ 0.6), or None.
    """
    pool = [str(c) for c in choices]
    if not ignore_case:
        hit = difflib.get_close_matches(str(word), pool, n=1, cutoff=0.6)
        return hit[0] if hit else None
    lowered = {c.lower(): c for c in pool}
    hit = difflib.get_close_matches(str(word).lower(), list(lowered), n=1, cutoff=0.6)
    return lowered[hit[0]] if hit else None


def did_you_mean(word: object, choices: Iterable[object], *, ignore_case: bool = True) -> str:
    """``"; did you mean 'x'?"`` for the nearest choice (see :func:`nearest`), or an empty string."""
    hit = nearest(word, choices, ignore_case=ignore_case)
    return f"; did you mean {hit!r}?" if hit is not None else ""


def named(items: Iterable[T], wanted: object, *, what: str, plural: str, key: str = "id", where: str = "") -> T:
    """The item whose ``key`` attribute equals ``wanted`` (a protocol's condition, a plan's test, a trait …).

    None: :class:`~studyctl.errors.UnknownKeyError` (a ``KeyError``) ``no {what} {wanted!r}{where}; {plural} are
    {the names in order}`` (``none`` when there are none) and the :func:`did_you_mean` hint, so every such lookup
    refuses in the same words.
    """
    pool = tuple(items)
    for item in pool:
        if getattr(item, key) == wanted:
            return item
    names = [getattr(i, key) for i in pool]
    known = ", ".join(map(str, names)) or "none"
    raise UnknownKeyError(f"no {what} {wanted!r}{where}; {plural} are {known}{did_you_mean(wanted, names)}")
