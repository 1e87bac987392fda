"""Input checking shared by every test: one place that turns user data into clean float arrays."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from studyctl.errors import StatsInputError

ALTERNATIVES = ("two-sided", "less", "greater")


def as_array(values: Any, name: str) -> np.ndarray:
    """Return ``values`` as a non-empty 1-D float64 array, NaN kept in place.

    Raises :class:`StatsInputError` for a string, non-numeric data, a scalar, more than one
    dimension or an empty input. ``None`` becomes NaN.
    """
    if isinstance(values, (str, bytes)):
        raise StatsInputError(f"{name} must be a sequence of numbers, got the string {values!r}")
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise StatsInputError(
            f"{name} must contain only numbers (NaN/None allowed for missing values): {exc}"
        ) from None
    if arr.ndim == 0:
        raise StatsInputError(f"{name} must be a 1-D sequence of numbers, got the scalar {arr.item()!r}")
    if arr.ndim != 1:
        raise StatsInputError(f"{name} must be 1-D, got an array of shape {arr.shape}")
    if arr.size == 0:
        raise StatsInputError(f"{name} is empty; it needs at least 1 value")
    return arr


def as_sample(values: Any, name: str, *, allow_inf: bool = True) -> tuple[np.ndarray, int]:
    """Return ``(finite-or-inf float64 1-D array without NaN, number of NaN dropped)``.

    Raises :class:`StatsInputError` as :func:`as_array` does, and (when ``allow_inf`` is false)
    for infinite values. ``None`` counts as missing like NaN.
    """
    arr = as_array(values, name)
    nan = np.isnan(arr)
    n_nan = int(nan.sum())
    if n_nan:
        arr = arr[~nan]
    if not allow_inf and not np.all(np.isfinite(arr)):
        raise StatsInputError(
            f"{name} contains an infinite value; only finite numbers (or NaN for missing) are allowed"
        )
    return arr, n_nan


def group_warnings(nan_dropped: int, empty: Sequence[str]) -> list[str]:
    """The opening warnings of a k-group test: missing values dropped, groups left with no values."""
    warnings = []
    if nan_dropped:
        warnings.append(f"{nan_dropped} missing value(s) dropped")
    if empty:
        warnings.append(f"group(s) {', '.join(empty)} have no values and were left out")
    return warnings


def check_alternative(alternative: str) -> str:
    if alternative not in ALTERNATIVES:
        raise StatsInputError(f"alternative must be one of {', '.join(map(repr, ALTERNATIVES))}, got {alternative!r}")
    return alternative


def check_choice(value: str, name: str, allowed: Sequence[str]) -> str:
    if value not in allowed:
        raise StatsInputError(f"{name} must be one of {', '.join(map(repr, allowed))}, got {value!r}")
    return value


def check_probability(value: Any, name: str) -> float:
    """A number strictly between 0 and 1 (a confidence level, α, a quantile's probability)."""
    try:
        c = float(value)
    except (TypeError, ValueError):
        raise StatsInputError(f"{name} must be a number in (0, 1), got {value!r}") from None
    if not (0.0 < c < 1.0):
        raise StatsInputError(f"{name} must be in the open interval (0, 1), got {value!r}")
    return c


def check_confidence(confidence: float) -> float:
    return check_probability(confidence, "confidence")


def check_count(value: Any, name: str) -> int:
    """A non-negative integer count (numbers with an integral value, e.g. a float64 sum, are accepted; text,
    booleans and fractions are not)."""
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise StatsInputError(f"{name} must be a non-negative integer, got {value!r}")
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise StatsInputError(f"{name} must be a non-negative integer, got {value!r}") from None
    if not np.isfinite(f) or f < 0 or f != int(f):
        raise StatsInputError(f"{name} must be a non-negative integer, got {value!r}")
    return int(f)


def split_groups(
    groups: tuple[Any, ...], names: Sequence[str] | None, *, min_groups: int, allow_inf: bool = True
) -> tuple[list[str], list[np.ndarray], list[int]]:
    """Normalise ``f(*groups)`` / ``f(mapping)`` / ``names=`` calls into names, clean arrays, NaN counts.

    A single mapping argument ``{"name": values, ...}`` names the groups by its keys; otherwise
    ``names`` (if given) must have one entry per group, and the default names are "1", "2", ….
    """
    if len(groups) == 1 and isinstance(groups[0], Mapping):
        if names is not None:
            raise StatsInputError("give group names either as mapping keys or with names=, not both")
        mapping = groups[0]
        names = [str(k) for k in mapping]
        groups = tuple(mapping.values())
    if len(groups) < min_groups:
        raise StatsInputError(f"need at least {min_groups} groups, got {len(groups)}")
    if names is None:
        names = [str(i + 1) for i in range(len(groups))]
    else:
        names = [str(n) for n in names]
        if len(names) != len(groups):
            raise StatsInputError(f"names has {len(names)} entries but there are {len(groups)} groups")
        if len(set(names)) != len(names):
            raise StatsInputError(f"names must be unique, got {names}")
    arrays, dropped = [], []
    for name, g in zip(names, groups, strict=True):
        arr, n_nan = as_sample(g, f"group {name!r}", allow_inf=allow_inf)
        arrays.append(arr)
        dropped.append(n_nan)
    return names, arrays, dropped
