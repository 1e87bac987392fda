"""The analysis tests as a registry; figure kinds listed once; every stats result read through one summary."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest
import yaml

from studyctl import stats
from studyctl.analysis import MetricTable, catalog, load_plan, run_plan
from studyctl.analysis.figure_data import COLLECTORS
from studyctl.analysis.procedures import EACH_CELL, REGISTRY, Cell, Finding, TestSpec
from studyctl.report.compose import _DRAWERS


def _force_table(rng: np.random.Generator) -> pd.DataFrame:
    """Mean contact force of 15 novices and 10 experts in two conditions."""
    rows = [
        {"participant": f"P{i:02d}", "group": "novice" if i < 15 else "expert", "condition": c, "trial": f"{i}{c}",
         "repetition": 1, "metric": "mean_contact_force", "level": None, "value": float(rng.normal(3, 0.5)),
         "denominator": np.nan}
        for i in range(25)
        for c in ("no_feedback", "linear")
    ]
    return pd.DataFrame(rows)


def test_every_registered_test_can_run_and_every_posthoc_is_registered():
    assert catalog.TESTS is REGISTRY
    for spec in REGISTRY.values():
        assert (spec.run is None) != (spec.tabulate is None), spec.name
        assert spec.design in (catalog.BETWEEN, catalog.WITHIN, catalog.PROPORTION, catalog.DESCRIPTIVE)
        if spec.tabulate is not None:
            assert spec.design == catalog.DESCRIPTIVE and spec.table in ("percent_change", "descriptives", "likert")
        if spec.pairwise:
            assert spec.each == EACH_CELL, spec.name
        for ph in spec.posthoc:
            name, _variant = catalog.POSTHOC_VARIANTS.get(ph, (ph, None))
            assert name in REGISTRY, f"{spec.name}: post-hoc {ph} is not registered"


def test_figure_kinds_are_listed_once():
    assert set(COLLECTORS) == set(catalog.SIGNAL_FIGURES)
    assert set(_DRAWERS) == set(catalog.FIGURE_KINDS)


def _summaries() -> list[stats.TestSummary]:
    x, y, z = [1.0, 2.5, 3.0, 4.2, 5.1], [2.0, 3.5, 4.1, 6.0, 7.3], [5.0, 6.5, 7.2, 8.1, 9.9]
    out = [
        stats.rank_sum(x, y).summary(),
        stats.signed_rank(x, y).summary(),
        stats.kruskal_wallis(x, y, z).summary(),
        stats.anova_oneway(x, y, z).summary(),
        stats.anova_oneway(x, y, z).summary(effect_size="omega_squared"),
        stats.friedman(x, y, z).summary(),
        stats.rm_anova(x, y, z).summary(),
        stats.wilson_interval(3, 10).summary(),
        stats.newcombe_interval(3, 10, 7, 10).summary(),
    ]
    out += [p.summary for p in stats.tukey_hsd(x, y, z, names=["x", "y", "z"]).pairs()]
    out += [p.summary for p in stats.dunn(x, y, z, names=["x", "y", "z"]).pairs()]
    return out


def test_every_result_reads_through_one_typed_summary():
    for s in _summaries():
        assert isinstance(s, stats.TestSummary)
        assert s.statistic_name and np.isfinite(s.statistic) and s.method
        assert np.isfinite(s.p) or np.isfinite(s.p_adj) or np.isfinite(s.ci_low)
    anova = stats.anova_oneway([1, 2, 3], [2, 3, 5], [6, 7, 9])
    assert anova.summary().effect_size == anova.eta_squared
    assert anova.summary(effect_size="omega_squared").effect_size == anova.omega_squared
    rm = stats.rm_anova([1, 2, 3, 4], [2, 3, 5, 4], [6, 7, 9, 8]).summary()
    assert rm.p == stats.rm_anova([1, 2, 3, 4], [2, 3, 5, 4], [6, 7, 9, 8]).pvalue_gg  # the corrected p


def test_a_new_test_is_one_registry_entry(monkeypatch, tmp_path):
    """A test added to the registry is validated, dispatched and tabulated like the built-in ones."""

    def median_gap(cell: Cell) -> list[Finding]:
        a, b = (float(np.median(s)) for s in cell.samples)
        assert cell.units is not None and set(cell.units["group"]) == set(cell.levels)  # the long rows too
        return [Finding(stats.TestSummary("median gap", b - a, method="toy: difference of medians"), None)]

    spec = TestSpec("median_gap", catalog.BETWEEN, median_gap, frozenset(), 2, 2, frozenset(), (), "toy", each="pair")
    monkeypatch.setitem(REGISTRY, "median_gap", spec)
    base = yaml.safe_load(open(load_plan("bio_inspired_palpation").source_path))
    base["figures"] = []
    base["tests"] = [{"id": "gap", "test": "median_gap", "metrics": ["mean_force"], "compare": "group"}]
    path = tmp_path / "plan.yaml"
    path.write_text(yaml.safe_dump(base))
    table = MetricTable(frame=_force_table(np.random.default_rng(3)), source="synthetic")
    (row,) = run_plan(load_plan(path), table).rows
    f = table.frame
    force = f[f.metric == "mean_contact_force"].groupby(["participant", "group"])["value"].mean().reset_index()
    want = np.median(force[force.group == "expert"].value) - np.median(force[force.group == "novice"].value)
    assert (row.test, row.kind, row.groups) == ("median_gap", "two_sample", "novice vs expert")
    assert row.statistic == pytest.approx(want) and row.method == "toy: difference of medians"
    assert row.significant is None and row.n_per_group == "15; 10"


def test_findings_and_cells_are_frozen():
    cell = Cell(levels=("a",), alpha=0.05)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cell.alpha = 0.1  # type: ignore[misc]
