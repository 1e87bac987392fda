"""Turn pydantic validation errors into :class:`Problem` lines with file positions.

Pydantic reports every field error in one pass; we map each error's location to the key path in the
YAML data, look up where that key or value is written, and word the message with what was found,
what is allowed and, for misspellings, the nearest valid key or value.
"""

from __future__ import annotations

import re
import types
import typing
from typing import Any

from pydantic import BaseModel, ValidationError

from studyctl.problems import KeyPath, Problem, one_of, show
from studyctl.protocol.schema import ID_PATTERN, Protocol
from studyctl.suggest import nearest
from studyctl.yamlmarks import MarkedData

_TYPE_WORDS = {
    "int_type": "an integer",
    "int_from_float": "an integer",
    "float_type": "a number",
    "string_type": "a string (quote values such as 1.0, yes or 007)",
    "bool_type": "true or false",
    "dict_type": "a mapping",
    "model_type": "a mapping",
    "model_attributes_type": "a mapping",
    "list_type": "a list",
    "none_required": "null",
}

# Field-specific wording of range errors, keyed by the last key of the path.
_RANGE_WHAT = {
    "time_limit_s": "time limit must be positive",
    "max_s": "familiarisation time must be positive",
    "points": "a scale needs at least 2 points",
    "break_s": "break must not be negative",
    "repetitions": "repetitions must be at least 1",
    "blocks": "blocks must be at least 1",
    "sites": "there must be at least 1 site",
}


#: how a YAML value's type is named in messages (bool before int: True is an int too)
_TYPE_NAMES = ((bool, "boolean"), (int, "integer"), (float, "number"), (str, "string"), (dict, "mapping"),
               (list, "list"))


def _typename(value: Any) -> str:
    return next((name for kind, name in _TYPE_NAMES if isinstance(value, kind)), type(value).__name__)


def _data_path(data: Any, loc: tuple[Any, ...]) -> KeyPath:
    """Follow pydantic's ``loc`` through the data, dropping union tags and ``[key]`` markers."""
    path: list[str | int] = []
    node = data
    for i, step in enumerate(loc):
        if isinstance(node, dict) and step in node:
            path.append(step)
            node = node[step]
        elif isinstance(node, list) and isinstance(step, int) and 0 <= step < len(node):
            path.append(step)
            node = node[step]
        elif i == len(loc) - 1 and step != "[key]":
            path.append(step)  # a missing key: it is not in the data
        else:
            continue
    return tuple(path)


def _unwrap(annotation: Any) -> list[Any]:
    """The model classes an annotation can hold (through Optional, list, dict, Annotated)."""
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _unwrap(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType, list, dict, tuple):
        out: list[Any] = []
        for arg in typing.get_args(annotation):
            out.extend(_unwrap(arg))
        return out
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return []


def model_at(path: KeyPath) -> type[BaseModel] | None:
    """The protocol section model whose keys live at ``path`` (None for free-form mappings)."""
    model: type[BaseModel] | None = Protocol
    for step in path:
        if model is None:
            return None
        if isinstance(step, int):
            continue
        field = model.model_fields.get(str(step))
        if field is None:
            return None
        candidates = _unwrap(field.annotation)
        model = candidates[0] if candidates else None
    return model


def _allowed_literals(path: KeyPath) -> list[str]:
    """The literal values allowed at ``path`` (for a nearest-value suggestion)."""
    parent = model_at(tuple(p for p in path[:-1]))
    key = next((p for p in reversed(path) if isinstance(p, str)), None)
    if parent is None or key is None or key not in parent.model_fields:
        return []
    values: list[str] = []

    def collect(annotation: Any) -> None:
        origin = typing.get_origin(annotation)
        if origin is typing.Literal:
            values.extend(str(a) for a in typing.get_args(annotation))
        else:
            for arg in typing.get_args(annotation):
                collect(arg)

    collect(parent.model_fields[key].annotation)
    return values


def problems_from_validation(exc: ValidationError, marked: MarkedData, filename: str) -> list[Problem]:
    """One :class:`Problem` per pydantic error, positioned in the YAML source."""
    problems: list[Problem] = []
    for error in exc.errors(include_url=False):
        kind = error["type"]
        loc = tuple(error["loc"])
        path = _data_path(marked.data, loc)
        value = error.get("input")
        ctx = error.get("ctx") or {}
        if kind == "extra_forbidden":
            model = model_at(path[:-1])
            choices = sorted(model.model_fields) if model is not None else []
            key = path[-1] if path else "?"
            problems.append(
                Problem(
                    filename,
                    marked.key_mark(path),
                    path,
                    "unknown key",
                    show(key),
                    one_of(choices),
                    nearest(str(key), choices),
                )
            )
            continue
        if kind == "missing":
            key = path[-1] if path else "?"
            problems.append(
                Problem(filename, marked.value_mark(path[:-1]), path, "missing required key", "nothing",
                        f"a value for {key!r}")
            )
            continue
        mark = marked.value_mark(path)
        if kind == "literal_error":
            choices = _allowed_literals(path) or re.findall(r"'([^']*)'", str(ctx.get("expected", "")))
            suggestion = nearest(str(value), choices) if isinstance(value, str) else None
            problems.append(Problem(filename, mark, path, "value not allowed", show(value), one_of(choices),
                                    suggestion))
        elif kind in _TYPE_WORDS:
            found = f"{_typename(value)} {show(value)}" if not isinstance(value, (dict, list)) else show(value)
            problems.append(Problem(filename, mark, path, "wrong type", found, _TYPE_WORDS[kind]))
        elif kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
            key = next((p for p in reversed(path) if isinstance(p, str)), "")
            what = (_RANGE_WHAT.get(str(key), "value out of range") if kind.startswith("greater")
                    else "value too large")  # the upper limits (studyctl.protocol.schema.MAX_*)
            sign = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}[kind]
            bound = next(iter(ctx.values())) if ctx else "?"
            integer = isinstance(bound, int) and isinstance(value, int) and not isinstance(value, bool)
            noun = "an integer" if integer else "a number"
            bound_text = f"{bound:g}" if isinstance(bound, float) else str(bound)
            problems.append(Problem(filename, mark, path, what, show(value), f"{noun} {sign} {bound_text}"))
        elif kind == "finite_number":
            problems.append(Problem(filename, mark, path, "number must be finite", show(value),
                                    "a finite number (not .inf or .nan)"))
        elif kind == "too_long":
            most = ctx.get("max_length")
            problems.append(Problem(filename, mark, path, "too many entries", f"{ctx.get('actual_length')} entries",
                                    f"at most {most}"))
        elif kind == "too_short":
            need = ctx.get("min_length", 1)
            problems.append(Problem(filename, mark, path, "too few entries", show(value),
                                    f"a list of at least {need} entr{'y' if need == 1 else 'ies'}"))
        elif kind == "string_pattern_mismatch":
            pattern = ctx.get("pattern", "")
            allowed = (
                "an id of letters, digits, '_' or '-' starting with a letter"
                if pattern == ID_PATTERN
                else f"text matching {pattern}"
            )
            problems.append(Problem(filename, mark, path, "invalid name", show(value), allowed))
        elif kind == "string_too_long":
            problems.append(Problem(filename, mark, path, "too long", show(value),
                                    f"at most {ctx.get('max_length')} characters"))
        else:
            problems.append(Problem(filename, mark, path, str(error.get("msg", kind)), show(value), "a valid value"))
    return problems
