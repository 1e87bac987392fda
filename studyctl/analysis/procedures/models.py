"""Model-based tests: aligned rank transform ANOVA, linear mixed model, ordinal (cumulative link) model.

Each reads the cell's long units (one row per participant × level, with the plan's second factor when
``options.factor`` names one) and gives one finding per model term; a design the model cannot fit comes
back as not-computed findings with the reason (:mod:`studyctl.stats.models`).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from studyctl.analysis.procedures.spec import BETWEEN, Cell, Finding, TestSpec, below
from studyctl.errors import StatsInputError
from studyctl.stats import models

_TERM_SEP = " × "


def factor_column(factor: str) -> str:
    # As analysis.shape.factor_column (not imported: shape imports the plan, which imports this registry).
    return factor if factor in ("condition", "group") else "level"


def _long(cell: Cell) -> tuple[pd.DataFrame, np.ndarray, str, str | None]:
    """The cell's units of the compared levels, the compared factor's level per unit (text) and the second
    factor's name, if any."""
    units = cell.units
    if units is None or units.empty:
        raise StatsInputError("no units in this cell")
    compare = cell.compare or "condition"
    col = factor_column(compare)
    second = cell.options.get("factor")
    inside = units[col].isin(cell.levels)
    data = units if inside.all() else units[inside]  # read only: no copy needed
    return data, data[col].astype(str).to_numpy(), compare, (str(second) if second else None)


def _findings(res: models.ModelResult, alpha: float) -> list[Finding]:
    out = []
    for t in res.terms:
        s = t.summary()
        sig = below(s.p, alpha) if t.status == "ok" and math.isfinite(s.p) else None
        out.append(Finding(s, sig, warnings=s.warnings, status=t.status, term=t.term.replace(":", _TERM_SEP)))
    return out


def _factors(cell: Cell) -> tuple[pd.DataFrame, dict, dict]:
    data, level, compare, second = _long(cell)
    factors = {compare: level}
    levels = {compare: list(cell.levels)}
    if second:
        col = factor_column(second)
        if col not in data:
            raise StatsInputError(f"the units have no column for the second factor {second!r}")
        factors = {second: data[col].astype(str).to_numpy(), **factors}
    return data, factors, levels


def _art(cell: Cell) -> list[Finding]:
    data, factors, levels = _factors(cell)
    if len(factors) < 2:
        raise StatsInputError("art_anova needs a second factor: options: {factor: group} (or another factor)")
    return _findings(models.art_anova(data["value"], factors, data["participant"], levels=levels), cell.alpha)


def _mixed(cell: Cell) -> list[Finding]:
    data, factors, levels = _factors(cell)
    return _findings(models.mixed_model(data["value"], factors, data["participant"], levels=levels), cell.alpha)


def _ordinal(cell: Cell) -> list[Finding]:
    data, level, compare, _ = _long(cell)
    res = models.ordinal_model(data["value"], level, levels=list(cell.levels),
                               subject=data["participant"])
    findings = _findings(res, cell.alpha)
    return [Finding(f.summary, f.significant, warnings=f.warnings, status=f.status, term=compare) for f in findings]


SPECS = (
    TestSpec(
        "art_anova",
        BETWEEN,
        _art,
        frozenset(),
        2,
        None,
        frozenset({"factor"}),
        ("partial_eta_squared",),
        "aligned rank transform ANOVA (Wobbrock et al. 2011) of two crossed factors: type III "
        "F on aligned ranks, or with repeated participants the likelihood-ratio χ² of a random-intercept model",
    ),
    TestSpec(
        "mixed_model",
        BETWEEN,
        _mixed,
        frozenset(),
        2,
        None,
        frozenset({"factor"}),
        (),
        "linear mixed model with a random intercept per participant (statsmodels MixedLM, ML fits): "
        "likelihood-ratio χ² per term",
    ),
    TestSpec(
        "ordinal",
        BETWEEN,
        _ordinal,
        frozenset(),
        2,
        None,
        frozenset(),
        ("nagelkerke_r2",),
        "cumulative logit (proportional odds) model of Likert answers (Newton-Raphson maximum likelihood, as R's "
        "clm): likelihood-ratio χ² of the compared factor",
    ),
)
