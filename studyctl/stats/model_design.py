"""The long-form design every model-based test starts from (:mod:`studyctl.stats.models` fits the tests,
:mod:`studyctl.stats.model_intervals` their intervals, both on the same design).

One value per observation with its factor levels and its participant becomes a frame (non-finite responses
dropped, levels as text); the factors' levels in the caller's order; the full-factorial terms; the design matrix
in sum-to-zero coding with each column's term; and the reasons a design or a response cannot be fitted, which both
modules return as "not computed" rather than raising.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from studyctl.errors import StatsInputError


def long_frame(y: Sequence[float], factors: dict[str, Sequence], subject: Sequence | None) -> pd.DataFrame:
    """Columns ``y``, one per factor and ``_subject`` (each row its own participant when ``subject`` is None);
    rows with a non-finite response are dropped."""
    yv = np.asarray(y, dtype=float)
    if not factors:
        raise StatsInputError("a model needs at least one factor")
    columns: dict[str, Any] = {"y": yv}
    for name, values in factors.items():
        if len(values) != len(yv):
            raise StatsInputError(f"factor {name!r} has {len(values)} values for {len(yv)} observations")
        columns[name] = _text(values)
    columns["_subject"] = _text(subject) if subject is not None else np.arange(len(yv)).astype(str)
    frame = pd.DataFrame(columns)
    finite = np.isfinite(yv)
    return frame if finite.all() else frame[finite].reset_index(drop=True)


def _text(values: Sequence) -> np.ndarray:
    """The values as text (a factor's levels, a subject's id); text already is kept as it is (no conversion)."""
    arr = np.asarray(values, dtype=object)
    if all(type(v) is str for v in arr.tolist()):
        return arr
    return pd.Series(list(values), dtype=object).astype(str).to_numpy()


def factorial_terms(names: Sequence[str]) -> list[tuple[str, ...]]:
    """Main effects, then two-way, … interactions (the full factorial)."""
    return [c for k in range(1, len(names) + 1) for c in itertools.combinations(names, k)]


def _sum_coding(values: np.ndarray, levels: list[str]) -> np.ndarray:
    """R's contr.sum: level i → unit vector i, the last level → −1 in every column."""
    k = len(levels)
    idx = np.array([levels.index(v) for v in values])
    out = np.zeros((len(values), k - 1))
    for j in range(k - 1):
        out[:, j] = (idx == j).astype(float)
    out[idx == k - 1, :] = -1.0
    return out


def design(frame: pd.DataFrame, names: Sequence[str], levels: dict[str, list[str]]) -> tuple[np.ndarray, list[int]]:
    """Full-factorial design matrix (intercept first, sum-to-zero contrasts) and each column's term index
    (−1 for the intercept; as R's ``assign`` minus one)."""
    coded = {n: _sum_coding(frame[n].to_numpy(), levels[n]) for n in names}
    cols = [np.ones((len(frame), 1))]
    assign = [-1]
    for t, term in enumerate(factorial_terms(names)):
        block = coded[term[0]]
        for n in term[1:]:
            block = np.einsum("ij,ik->ijk", block, coded[n]).reshape(len(frame), -1)
        cols.append(block)
        assign += [t] * block.shape[1]
    return np.hstack(cols), assign


def factor_levels(frame: pd.DataFrame, names: Sequence[str], order: dict[str, Sequence[str]] | None) -> dict[str, list]:
    out = {}
    for n in names:
        present = list(dict.fromkeys(frame[n]))
        preferred = [str(v) for v in (order or {}).get(n, [])]
        out[n] = [v for v in preferred if v in present] + [v for v in present if v not in preferred]
    return out


def term_name(term: tuple[str, ...]) -> str:
    return ":".join(term)


def design_problem(frame: pd.DataFrame, names: Sequence[str], levels: dict[str, list]) -> str:
    """Why the full-factorial design cannot be fitted ('' when it can)."""
    for n in names:
        if len(levels[n]) < 2:
            return f"factor {n} has one level ({', '.join(levels[n]) or 'none'}) in these data"
    # the distinct level combinations present (what groupby(names).size() counts, without its machinery)
    cells = len({tuple(r) for r in zip(*(frame[n].tolist() for n in names), strict=True)})
    expected = math.prod(len(levels[n]) for n in names)
    if cells < expected:
        return (f"{expected - cells} of {expected} cells of {' × '.join(names)} have no observation: the "
                "full-factorial model is singular")
    if len(frame) <= expected:
        return f"no replication: {len(frame)} observations for {expected} cells"
    return ""


def no_variation(values: np.ndarray, what: str = "every value") -> str:
    """Why a response that does not vary cannot be tested ('' when it varies)."""
    if len(values) and np.all(values == values[0]):
        return f"{what} is the same ({values[0]:g}): the response does not vary, nothing to test"
    return ""


def has_repeats(frame: pd.DataFrame) -> bool:
    """Is any participant seen in more than one row (a within-participant design)?"""
    return bool(frame["_subject"].duplicated().any())


def ordinal_problem(frame: pd.DataFrame, levels: dict[str, list]) -> str:
    """Why a cumulative logit model of the answers ``frame["y"]`` on ``frame["factor"]`` cannot be fitted
    ('' when it can): the design's problems, answers that are not whole numbers, or no second answer."""
    why = design_problem(frame, ["factor"], levels)
    values = frame["y"].to_numpy()
    if not why and np.any(values != np.round(values)):
        why = ("answers are not whole numbers (repetitions averaged?): an ordinal model needs the answers "
               "themselves (aggregate: none)")
    if not why and len(np.unique(values)) < 2:
        why = "every answer is the same: no thresholds to estimate"
    return why


__all__ = ["design", "design_problem", "factor_levels", "factorial_terms", "has_repeats", "long_frame", "no_variation",
           "ordinal_problem", "term_name"]
