"""Declared plugin parameters: defaults, allowed ranges, and where each value comes from.

A plugin lists its parameters once as :class:`Param` objects; :func:`validate_params` merges the
protocol's values over the defaults and rejects unknown names, wrong types and values out of range
with one clear :class:`~studyctl.errors.ModelParameterError` line. The ``source`` of a parameter says
which paper, code or measurement gave its default, or that the value was chosen here (and why).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from studyctl.errors import ModelParameterError
from studyctl.suggest import did_you_mean, nearest


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


def _check(spec: Param, value: Any) -> tuple[tuple[str, str] | None, Any]:
    """((what is wrong in a word, the sentence for messages), or None when allowed; the converted value)."""
    allowed = spec.allowed()
    if spec.choices is not None:
        return (None, value) if value in spec.choices else (("not allowed", f"is not allowed; use {allowed}"), value)
    if spec.kind is bool:
        return (None, value) if isinstance(value, bool) else (("not true or false", "must be true or false"), value)
    if spec.kind in (int, float):
        if isinstance(value, bool) or not isinstance(value, int | float):
            return ("not a number", f"must be {allowed}"), value
        if spec.kind is int and not float(value).is_integer():
            return ("not a whole number", f"must be a whole number in {allowed}"), value
        number = spec.kind(value)
        if not math.isfinite(number):
            return ("not finite", f"must be finite; use {allowed}"), value
        if (spec.low is not None and number < spec.low) or (spec.high is not None and number > spec.high):
            return ("out of range", f"is out of range; use {allowed}"), value
        return None, number
    if spec.kind in (list, tuple):
        return (None, tuple(value)) if isinstance(value, list | tuple) else (("not a list", "must be a list"), value)
    if not isinstance(value, spec.kind):
        return ("wrong type", f"must be a {spec.kind.__name__}"), value
    return None, value


def _coerce(owner: str, spec: Param, value: Any) -> Any:
    refused, converted = _check(spec, value)
    if refused is not None:
        raise ModelParameterError(f"{owner}: parameter {spec.name!r} = {value!r} {refused[1]}")
    return converted


@dataclass(frozen=True)
class ParamProblem:
    """One refused parameter of a plugin, for checks that report every problem with its place in a file.

    ``key`` is the path inside the plugin's ``params`` mapping (``("liver", "k_cut")`` for a nested block, ``()``
    for the mapping as a whole); ``what`` says what is wrong, ``allowed`` what would do; ``at_key`` marks an
    unknown name (point at the key, not its value).
    """

    key: tuple[str, ...]
    what: str
    allowed: str
    suggestion: str | None = None
    at_key: bool = False


def unknown_param(key: tuple[str, ...], known: Iterable[str]) -> ParamProblem:
    """The problem of a parameter name the plugin does not declare, with the nearest known name."""
    names = sorted(known)
    allowed = ("one of " + ", ".join(repr(n) for n in names)) if names else "no parameters"
    return ParamProblem(key, "unknown parameter", allowed, nearest(str(key[-1]), names), True)


def param_problems(params: Mapping[str, Any] | None, spec: Sequence[Param]) -> list[ParamProblem]:
    """Every unknown name and refused value in ``params`` (what :func:`validate_params` raises for the first)."""
    by_name = {p.name: p for p in spec}
    problems = []
    for key, value in dict(params or {}).items():
        if key not in by_name:
            problems.append(unknown_param((key,), by_name))
            continue
        refused, _ = _check(by_name[key], value)
        if refused is not None:
            problems.append(ParamProblem((key,), refused[0], by_name[key].allowed()))
    return problems


def declared_problems(plugin: type, params: Mapping[str, Any] | None) -> list[ParamProblem]:
    """What a plugin class refuses in ``params``: its own ``param_problems(params)`` classmethod when it has one
    (plugins whose parameters nest or depend on each other), else a check against its declared ``PARAMS``;
    nothing for a plugin that declares neither."""
    own = getattr(plugin, "param_problems", None)
    if callable(own):
        return list(own(params or {}))
    spec = getattr(plugin, "PARAMS", None)
    return [] if spec is None else param_problems(params, spec)


def checked_problems(
    params: Mapping[str, Any] | None, spec: Sequence[Param], check: Callable[[Mapping[str, Any]], Any], owner: str
) -> list[ParamProblem]:
    """What a plugin with rules between its parameters refuses: each value against ``spec`` (every problem at its
    key), then, when they all pass, the plugin's own ``check(params)`` (the rules between them), whose
    :class:`~studyctl.errors.ModelParameterError` becomes a problem at the field it names first, else at the
    mapping. ``owner`` is the prefix of ``check``'s messages (``"scene needle_liver: "``)."""
    problems = param_problems(params, spec)
    if problems:
        return problems
    try:
        check(dict(params or {}))
    except ModelParameterError as exc:
        text = str(exc).removeprefix(owner)
        field = text.split(" ", 1)[0]
        key = (field,) if field in dict(params or {}) else ()
        return [ParamProblem(key, "refused", text)]
    return []


def problems_with_rules(
    spec: Sequence[Param], check: Callable[[Mapping[str, Any]], Any], owner: str
) -> classmethod:
    """A plugin class's ``param_problems`` (what ``studyctl protocol check`` asks) from its declared ``spec`` and
    the check of the rules between its parameters: ``param_problems = problems_with_rules(PARAMS, check, owner)``
    (see :func:`checked_problems`)."""

    def param_problems(cls: type, params: Mapping[str, Any]) -> list[ParamProblem]:
        return checked_problems(params, spec, check, owner)

    return classmethod(param_problems)


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
