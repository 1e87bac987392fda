"""Declared plugin parameters: defaults, allowed ranges, and where each value comes from.

A plugin lists its parameters once as :class:`Param` objects; :func:`validate_params` merges the
protocol's values over the defaults and rejects unknown names, wrong types and values out of range
with one clear :class:`~studyctl.errors.ModelParameterError` line. The ``source`` of a parameter says
which paper, code or measurement gave its default, or that the value was chosen here (and why).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from studyctl.errors import ModelParameterError
from studyctl.suggest import did_you_mean


@dataclass(frozen=True)
class Param:
    """One parameter: default, allowed range or choices, unit and the source of the default."""

    name: str
    default: Any
    low: float | None = None
    high: float | None = None
    choices: tuple[Any, ...] | None = None
    kind: type = float
    unit: str = ""
    source: str = ""
    doc: str = ""

    def allowed(self) -> str:
        """Human-readable allowed values."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind is bool:
            return "true or false"
        low = "-inf" if self.low is None else f"{self.low:g}"
        high = "inf" if self.high is None else f"{self.high:g}"
        unit = f" {self.unit}" if self.unit else ""
        return f"a {self.kind.__name__} in [{low}, {high}]{unit}"


def _coerce(owner: str, spec: Param, value: Any) -> Any:
    where = f"{owner}: parameter {spec.name!r}"
    if spec.choices is not None:
        if value not in spec.choices:
            raise ModelParameterError(f"{where} = {value!r} is not allowed; use {spec.allowed()}")
        return value
    if spec.kind is bool:
        if not isinstance(value, bool):
            raise ModelParameterError(f"{where} = {value!r} must be true or false")
        return value
    if spec.kind in (int, float):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ModelParameterError(f"{where} = {value!r} must be {spec.allowed()}")
        if spec.kind is int and not float(value).is_integer():
            raise ModelParameterError(f"{where} = {value!r} must be a whole number in {spec.allowed()}")
        number = spec.kind(value)
        if not math.isfinite(number):
            raise ModelParameterError(f"{where} = {value!r} must be finite; use {spec.allowed()}")
        if (spec.low is not None and number < spec.low) or (spec.high is not None and number > spec.high):
            raise ModelParameterError(f"{where} = {value!r} is out of range; use {spec.allowed()}")
        return number
    if spec.kind in (list, tuple):
        if not isinstance(value, list | tuple):
            raise ModelParameterError(f"{where} = {value!r} must be a list")
        return tuple(value)
    if not isinstance(value, spec.kind):
        raise ModelParameterError(f"{where} = {value!r} must be a {spec.kind.__name__}")
    return value


def validate_params(owner: str, params: Mapping[str, Any] | None, spec: Sequence[Param]) -> dict[str, Any]:
    """Merge ``params`` over the spec's defaults and check every value.

    Parameters
    ----------
    owner : str
        Plugin name used in messages (``"bio_inspired controller"``).
    params : mapping or None
        Values from the protocol.
    spec : sequence of Param
        The declared parameters.

    Returns
    -------
    dict
        Every declared parameter with its checked value.

    Raises
    ------
    ModelParameterError
        Unknown name (with the nearest valid one), wrong type or value out of range.
    """
    by_name = {p.name: p for p in spec}
    out = {p.name: p.default for p in spec}
    for key, value in dict(params or {}).items():
        if key not in by_name:
            raise ModelParameterError(
                f"{owner}: unknown parameter {key!r}{did_you_mean(key, by_name)}"
                f" Known parameters: {', '.join(sorted(by_name)) or 'none'}"
            )
        out[key] = _coerce(owner, by_name[key], value)
    return out


def describe(spec: Iterable[Param]) -> list[dict[str, Any]]:
    """Rows (name, default, allowed, unit, source) for documentation and ``plugins list --params``."""
    return [
        {"name": p.name, "default": p.default, "allowed": p.allowed(), "unit": p.unit, "source": p.source}
        for p in spec
    ]
