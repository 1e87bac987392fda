"""Confidence intervals of the effect sizes of a result's tests, by the percentile bootstrap.

For each omnibus or two-sample row with an effect size, the participants' values of that row's cell (from the
result's units table, shaped as the runner shapes them) are resampled with a seeded
:class:`numpy.random.Generator` — within each level for independent samples, whole participants (complete
blocks) for paired designs — the row's test is run again on every resample, and the 2.5 and 97.5 percentiles
of its effect size are the interval. The generator's seed is (``seed``, CRC-32 of the row's key), so an
interval never depends on which other rows were computed. Model-based tests (ART, mixed, ordinal) and
intervals of proportions are left out (their rows say so in ``method``).

Only reports pay for this (power and calibration runs do not call it).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd

from studyctl.analysis import catalog
from studyctl.analysis.procedures import Cell
from studyctl.analysis.results import AnalysisResult
from studyctl.analysis.shape import factor_column, row_units
from studyctl.errors import StudyctlError
from studyctl.stats.kruskal import epsilon_squared
from studyctl.stats.ranksum import rank_biserial
from studyctl.stats.repeated import rm_partial_eta_squared

COLUMNS = ("test_id", "metric", "split", "groups", "effect_size_name", "effect_size", "ci_low", "ci_high",
           "ci_level", "replicates", "seed", "method")
_SKIP = {"art_anova", "mixed_model", "ordinal"}


# Tests whose effect size has a function of its own, giving the test's floats bit for bit without its p-value and
# result objects (per resample: rank-sum 85 -> 30 us, RM-ANOVA 233 -> ~145 us; rank-sum and Kruskal-Wallis are
# 24,000 of seed 000's 28,000 resampled tests, RM-ANOVA 4,000 of seed 001's 12,000). Used when the plan sets none of
# the test's options but those in _HARMLESS; any other test runs whole.
_EFFECT_ONLY: dict[str, Callable[..., float]] = {
    "rank_sum": rank_biserial,
    "kruskal_wallis": epsilon_squared,
    "rm_anova": rm_partial_eta_squared,
}
# Option values that leave a test's effect size as it is and cannot make the test fail on a resample (an exact
# rank-sum p can: too large a sample). Seed 000's plan spells out rank-sum's defaults, alternative and method.
_HARMLESS: dict[str, dict[str, tuple[Any, ...]]] = {
    "rank_sum": {"alternative": ("two-sided", "less", "greater"), "continuity": (True, False),
                 "method": ("auto", "asymptotic")},
}


def _effect_only(test: str, options: Mapping[str, Any]) -> Callable[..., float] | None:
    harmless = _HARMLESS.get(test, {})
    if any(key not in harmless or value not in harmless[key] for key, value in options.items()):
        return None
    return _EFFECT_ONLY.get(test)


def _effect_of(spec: catalog.TestSpec, template: Cell) -> Callable[[tuple[np.ndarray, ...]], float]:
    """The effect size of ``spec`` run on resampled ``samples`` (NaN where the test fails)."""
    only = _effect_only(spec.name, template.options)

    def run(samples: tuple[np.ndarray, ...]) -> float:
        try:
            if only is not None:
                return float(only(*samples))
            (finding,) = spec.run(replace(template, samples=samples))
        except (StudyctlError, ValueError):
            return math.nan
        return float(finding.summary.effect_size)

    return run


def effect_size_intervals(result: AnalysisResult, *, replicates: int = 1000, seed: int = 20,
                          confidence: float = 0.95) -> pd.DataFrame:
    """One row per bootstrapped effect size (columns :data:`COLUMNS`)."""
    units = result.tables.get("units", pd.DataFrame())
    frame = result.to_frame()
    rows = []
    if units.empty:
        return pd.DataFrame(columns=list(COLUMNS))
    entries = {e.id: e for e in result.plan.tests}
    for r in frame.itertuples(index=False):
        entry = entries.get(r.test_id)
        if entry is None or r.status != "ok" or r.kind not in ("omnibus", "two_sample") or r.test in _SKIP:
            continue
        if not r.effect_size_name or not math.isfinite(r.effect_size):
            continue
        spec = catalog.TESTS[catalog.ALIASES.get(r.test, r.test)]
        if spec.run is None or spec.design not in (catalog.BETWEEN, catalog.WITHIN):
            continue
        levels = r.groups.split(" vs ") if r.kind == "two_sample" else r.groups.split(", ")
        col = factor_column(entry.compare)
        sel = row_units(units, r.metric, r.split)
        keys = ["participant", col, *[factor_column(b) for b in entry.by]]
        sel = sel.groupby(keys, dropna=False)["value"].mean().reset_index()
        sel = sel[sel[col].astype(str).isin(levels)]
        key = f"{r.test_id}|{r.metric}|{r.split}|{r.groups}"
        rng = np.random.default_rng([seed, zlib.crc32(key.encode())])
        template = Cell(levels=tuple(levels), alpha=float(r.alpha), options=dict(entry.options),
                        effect_size=entry.effect_size[0] if entry.effect_size else None, compare=entry.compare)
        run = _effect_of(spec, template)
        boot = np.full(replicates, math.nan)
        if spec.design == catalog.WITHIN:
            wide = sel.pivot_table(index="participant", columns=col, values="value", aggfunc="mean")
            wide = wide.reindex(columns=levels).dropna().to_numpy(dtype=float)
            if len(wide) < 2:
                continue
            for b in range(replicates):
                pick = wide[rng.integers(0, len(wide), len(wide))]
                boot[b] = run(tuple(pick[:, j] for j in range(pick.shape[1])))
        else:
            samples = [sel.loc[sel[col].astype(str) == lv, "value"].to_numpy(dtype=float) for lv in levels]
            samples = [s[np.isfinite(s)] for s in samples]
            if any(len(s) < 2 for s in samples):
                continue
            for b in range(replicates):
                boot[b] = run(tuple(s[rng.integers(0, len(s), len(s))] for s in samples))
        ok = boot[np.isfinite(boot)]
        if len(ok) < replicates // 2:
            continue
        lo, hi = np.quantile(ok, [(1 - confidence) / 2, (1 + confidence) / 2])
        rows.append({"test_id": r.test_id, "metric": r.metric, "split": r.split, "groups": r.groups,
                     "effect_size_name": r.effect_size_name, "effect_size": r.effect_size, "ci_low": float(lo),
                     "ci_high": float(hi), "ci_level": confidence, "replicates": int(len(ok)), "seed": seed,
                     "method": "percentile bootstrap, resampling "
                     + ("participants (complete blocks)" if spec.design == catalog.WITHIN
                        else "within each level")})
    return pd.DataFrame(rows, columns=list(COLUMNS))
