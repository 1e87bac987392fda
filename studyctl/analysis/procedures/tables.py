"""Descriptive entries: percent change against a reference level, cell descriptives, Likert tables."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from studyctl.analysis.procedures.spec import DESCRIPTIVE, Cell, TestSpec

NAN = math.nan


def describe(vals: np.ndarray) -> dict[str, float]:
    """n, mean, SD, SE, median, quartiles, min and max of the finite values."""
    v = vals[np.isfinite(vals)]
    n = len(v)
    if n == 0:
        return {"n": 0, "mean": NAN, "sd": NAN, "se": NAN, "median": NAN, "q1": NAN, "q3": NAN, "min": NAN, "max": NAN}
    sd = float(np.std(v, ddof=1)) if n > 1 else NAN
    return {
        "n": n,
        "mean": float(v.mean()),
        "sd": sd,
        "se": sd / math.sqrt(n) if n > 1 else NAN,
        "median": float(np.median(v)),
        "q1": float(np.quantile(v, 0.25)),
        "q3": float(np.quantile(v, 0.75)),
        "min": float(v.min()),
        "max": float(v.max()),
    }


def _percent_change(cell: Cell) -> list[dict[str, Any]]:
    means = {lv: float(np.nanmean(v)) if len(v) else NAN for lv, v in zip(cell.levels, cell.samples, strict=True)}
    ref = cell.reference
    ref_mean = means.get(ref, NAN) if ref is not None else NAN
    return [
        {
            "level": lv,
            "reference": ref,
            "mean": means[lv],
            "reference_mean": ref_mean,
            "percent_change": 100.0 * (means[lv] - ref_mean) / ref_mean if ref_mean not in (0.0,) else NAN,
            "n": len(v),
        }
        for lv, v in zip(cell.levels, cell.samples, strict=True)
    ]


def _describe_levels(cell: Cell) -> list[dict[str, Any]]:
    return [{"level": lv, **describe(v)} for lv, v in zip(cell.levels, cell.samples, strict=True)]


SPECS = (
    TestSpec(
        "percent_change",
        DESCRIPTIVE,
        None,
        frozenset(),
        2,
        None,
        frozenset(),
        ("percent_change",),
        "percent change of the mean against a reference level",
        tabulate=_percent_change,
        table="percent_change",
    ),
    TestSpec(
        "descriptive",
        DESCRIPTIVE,
        None,
        frozenset(),
        1,
        None,
        frozenset(),
        (),
        "n, mean, SD, SE, median and quartiles per cell",
        tabulate=_describe_levels,
        table="descriptives",
    ),
    TestSpec(
        "likert_table",
        DESCRIPTIVE,
        None,
        frozenset(),
        1,
        None,
        frozenset(),
        (),
        "mean Likert score per item and level",
        tabulate=_describe_levels,
        table="likert",
    ),
)
