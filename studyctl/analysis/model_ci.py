"""Fixed effects with confidence intervals for a result's model tests (``mixed_model``, ``ordinal``).

For each metric (and split) such a test ran on, the same units the test used (the result's ``units`` table:
one value per participant × level, or every answer for Likert items) are fitted once more for the
coefficients in treatment coding, each with its Wald interval (:mod:`studyctl.stats.model_intervals`: the
same numbers as R's ``confint(lmer(...), method = "Wald")`` and ``confint.default(clm(...))``). Only reports
pay for this (``model_coefficients.csv``); power and calibration runs do not call it.
"""

from __future__ import annotations

import math

import pandas as pd

from studyctl.analysis import catalog
from studyctl.analysis.results import AnalysisResult
from studyctl.analysis.shape import factor_column, ordered_levels, row_units
from studyctl.stats.model_intervals import mixed_coefficients, ordinal_coefficients

COLUMNS = ("test_id", "metric", "split", "model", "coefficient", "estimate", "se", "ci_low", "ci_high", "ci_level",
           "method", "status", "reason")
MODELS = ("mixed_model", "ordinal")


def model_coefficient_intervals(result: AnalysisResult, *, confidence: float = 0.95) -> pd.DataFrame:
    """One row per coefficient of every mixed-model and ordinal test of ``result`` (columns :data:`COLUMNS`)."""
    units = result.tables.get("units", pd.DataFrame())
    entries = {e.id: e for e in result.plan.tests}
    rows: list[dict] = []
    if units.empty:
        return pd.DataFrame(columns=list(COLUMNS))
    seen: set[tuple[str, str, str]] = set()
    for r in result.to_frame().itertuples(index=False):
        entry = entries.get(r.test_id)
        name = catalog.ALIASES.get(r.test, r.test)
        key = (r.test_id, r.metric, r.split)
        if entry is None or name not in MODELS or key in seen or r.status != "ok":
            continue
        seen.add(key)
        sel = row_units(units, r.metric, r.split)
        col = factor_column(entry.compare)
        # the runner's level order, so the coefficients are against the level its rows name first
        levels = ordered_levels(sel[col].astype(str), result.plan.level_order(entry.compare, entry))
        sel = sel[sel[col].astype(str).isin(levels) & sel["value"].map(lambda v: math.isfinite(float(v)))]
        if name == "mixed_model":
            factors, order = {}, {entry.compare: levels}
            second = entry.options.get("factor")
            if second:
                values = sel[factor_column(second)].astype(str)
                factors[second] = values.to_numpy()
                order[second] = ordered_levels(values, result.plan.level_order(second, entry))
            factors[entry.compare] = sel[col].astype(str).to_numpy()
            table = mixed_coefficients(sel["value"].to_numpy(dtype=float), factors, sel["participant"].to_numpy(),
                                       levels=order, confidence=confidence)
            rename = {}
        else:
            table = ordinal_coefficients(sel["value"].to_numpy(dtype=float), sel[col].astype(str).to_numpy(),
                                         levels=levels, confidence=confidence)
            rename = {"factor[": f"{entry.compare}["}
        head = {"test_id": r.test_id, "metric": r.metric, "split": r.split, "model": name,
                "ci_level": table.ci_level, "method": table.method, "status": table.status, "reason": table.reason}
        if table.status != "ok":
            rows.append(head | {"coefficient": "", "estimate": math.nan, "se": math.nan, "ci_low": math.nan,
                                "ci_high": math.nan})
            continue
        for c in table.coefficients:
            label = c.name
            for old, new in rename.items():
                label = label.replace(old, new)
            rows.append(head | {"coefficient": label, "estimate": c.estimate, "se": c.se, "ci_low": c.ci_low,
                                "ci_high": c.ci_high})
    return pd.DataFrame(rows, columns=list(COLUMNS))
