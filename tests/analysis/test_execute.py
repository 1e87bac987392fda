"""Running plans on metric tables: row shapes, missing-data policies, degenerate inputs, corrections."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from studyctl import stats
from studyctl.analysis import MetricTable, load_plan, run_plan
from studyctl.analysis.results import ROW_COLUMNS
from studyctl.errors import AnalysisError
from studyctl.stats import adjust_pvalues

CONDITIONS = ["no_feedback", "piecewise", "linear", "bio_inspired"]
EFFECT = dict(zip(CONDITIONS, [0.0, 0.3, 0.6, 0.9], strict=True))


def seed000_table(rng: np.random.Generator, n: int = 25) -> pd.DataFrame:
    """Values shaped like seed 000's data (15 novices, 10 experts, one trial per condition)."""
    rows = []
    for i in range(n):
        group = "novice" if i < 15 else "expert"
        for c in CONDITIONS:
            e = EFFECT[c]
            base = {"participant": f"P{i:02d}", "group": group, "condition": c, "trial": f"{i}-{c}", "repetition": 1}
            for metric, value in (
                ("localisation_accuracy", float(np.clip(0.3 + 0.5 * e + rng.normal(0, 0.15), 0, 1))),
                ("mean_contact_force", 3 - 1.2 * e + rng.normal(0, 0.4)),
                ("completion_time", 60 + rng.normal(0, 10)),
                ("tumour_contact_time", 3 - e + rng.normal(0, 0.5)),
            ):
                rows.append({**base, "metric": metric, "level": None, "value": value, "denominator": np.nan})
            for cls, p in (("soft", 0.2), ("medium", 0.5), ("hard", 0.8)):
                hit = float(rng.random() < p + e * (1 - p))
                rows.append({**base, "metric": "detection", "level": cls, "value": hit, "denominator": 1.0})
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def plan():
    return load_plan("bio_inspired_palpation")


@pytest.fixture(scope="module")
def lean_plan(plan):
    """The plan without its model-based entries (ART ANOVA, mixed model): their statsmodels fits cost ~3 s of CPU
    per run, and the missing-data and degenerate-input tests below read only the rank tests' rows."""
    keep = [t for t in plan.tests if t.test not in ("art_anova", "mixed_model")]
    assert len(keep) < len(plan.tests)
    return plan.model_copy(update={"tests": keep})


@pytest.fixture(scope="module")
def table():
    return MetricTable(frame=seed000_table(np.random.default_rng(2024)), source="synthetic")


@pytest.fixture(scope="module")
def result(plan, table):
    return run_plan(plan, table)


@pytest.mark.slow
def test_rows_per_entry(result):
    frame = result.to_frame()
    assert list(frame.columns) == list(ROW_COLUMNS)
    count = frame.groupby(["test_id", "kind"]).size().to_dict()
    assert count[("novice_vs_expert", "two_sample")] == 16  # 4 metrics × 4 conditions, as in the paper
    assert count[("control_algorithm", "omnibus")] == 4
    assert count[("tumour_class", "omnibus")] == 4
    assert count[("detection_probability", "interval")] == 12
    assert count[("within_subject", "omnibus")] == 4
    assert (frame["status"] == "ok").all()
    assert not result.partial


def test_rows_agree_with_the_stats_functions(result, table):
    """The runner forms the right samples: recompute two rows directly."""
    f = table.frame
    sel = f[(f.metric == "mean_contact_force") & (f.condition == "linear")]
    x = sel[sel.group == "novice"]["value"].to_numpy()
    y = sel[sel.group == "expert"]["value"].to_numpy()
    direct = stats.rank_sum(x, y)
    (row,) = [
        r for r in result.rows_for("novice_vs_expert") if r.metric == "mean_force" and r.split == "condition=linear"
    ]
    assert row.statistic == pytest.approx(direct.statistic) and row.p == pytest.approx(direct.pvalue)
    assert row.groups == "novice vs expert" and row.n_per_group == "15; 10"
    groups = [f[(f.metric == "tumour_contact_time") & (f.condition == c)]["value"].to_numpy() for c in CONDITIONS]
    kw = stats.kruskal_wallis(*groups)
    (omni,) = [r for r in result.rows_for("control_algorithm") if r.metric == "contact_time" and r.kind == "omnibus"]
    assert omni.statistic == pytest.approx(kw.statistic) and omni.p == pytest.approx(kw.pvalue)


def test_posthoc_only_after_a_main_effect(result):
    rows = result.rows_for("control_algorithm")
    for metric in {r.metric for r in rows}:
        omni = [r for r in rows if r.metric == metric and r.kind == "omnibus"][0]
        post = [r for r in rows if r.metric == metric and r.kind == "posthoc"]
        if omni.p < 0.05:
            assert len(post) == 6 and all(r.parent == f"control_algorithm/{metric}" for r in post)
        else:
            assert post == [] and "post-hoc multcompare not run" in omni.warnings


def test_detection_probability_counts(result, table):
    f = table.frame
    (row,) = [
        r for r in result.rows_for("detection_probability") if r.split == "condition=no_feedback" and r.groups == "soft"
    ]
    sel = f[(f.metric == "detection") & (f.condition == "no_feedback") & (f.level == "soft")]
    assert row.n_per_group == f"{int(sel.value.sum())}/25"
    w = stats.wilson_interval(int(sel.value.sum()), 25)
    assert (row.estimate, row.ci_low, row.ci_high) == pytest.approx((w.estimate, w.lower, w.upper))


def drop(frame: pd.DataFrame, participant: str, condition: str) -> pd.DataFrame:
    return frame[~((frame.participant == participant) & (frame.condition == condition))]


def test_missing_available_uses_complete_blocks_for_paired_tests(lean_plan):
    frame = drop(seed000_table(np.random.default_rng(7)), "P03", "linear")
    result = run_plan(lean_plan, MetricTable(frame=frame, source="synthetic"))
    within = [r for r in result.rows_for("within_subject") if r.kind == "omnibus"][0]
    assert within.n == 24 and "1 participant(s) without values in every compared level" in within.warnings
    assert "P03" in within.warnings
    between = [r for r in result.rows_for("control_algorithm") if r.kind == "omnibus"][0]
    assert between.n_per_group == "25; 25; 24; 25"


def test_missing_complete_cases_and_fail(lean_plan):
    frame = drop(seed000_table(np.random.default_rng(7)), "P03", "linear")
    strict = lean_plan.model_copy(update={"missing": "complete_cases"})
    result = run_plan(strict, MetricTable(frame=frame, source="synthetic"))
    between = [r for r in result.rows_for("control_algorithm") if r.kind == "omnibus"][0]
    assert between.n_per_group == "24; 24; 24; 24"
    assert set(result.missing["participant"]) == {"P03"}
    assert result.missing["reason"].str.contains("complete_cases").all()
    with pytest.raises(AnalysisError, match=r"participant\(s\) lack values in some condition: P03 \(linear\)"):
        run_plan(lean_plan.model_copy(update={"missing": "fail"}), MetricTable(frame=frame, source="synthetic"))


def test_condition_with_one_participant_is_computed_and_flagged(lean_plan):
    frame = seed000_table(np.random.default_rng(3))
    keep = (frame.condition != "linear") | (frame.participant == "P00")
    result = run_plan(lean_plan, MetricTable(frame=frame[keep], source="synthetic"))
    omni = [r for r in result.rows_for("control_algorithm") if r.kind == "omnibus"][0]
    assert omni.status == "ok" and "only 1 value in linear" in omni.warnings
    # within one condition the groups compare 1 novice with 0 experts: not computable, and said so
    lin = [r for r in result.rows_for("novice_vs_expert") if r.split == "condition=linear"]
    assert lin and all(r.status == "not_computed" for r in lin)
    assert result.partial


def test_no_values_and_absent_condition(lean_plan):
    with pytest.raises(AnalysisError, match="no metric values at all; run sessions first"):
        run_plan(lean_plan, MetricTable(frame=seed000_table(np.random.default_rng(1)).iloc[0:0], source="empty.db"))
    frame = seed000_table(np.random.default_rng(1))
    result = run_plan(lean_plan, MetricTable(frame=frame[frame.condition != "piecewise"], source="synthetic"))
    assert "condition 'piecewise': no values in the data" in result.problems
    assert result.partial


def test_unplanned_condition_is_noted_not_dropped_silently(lean_plan):
    frame = seed000_table(np.random.default_rng(1))
    extra = frame[frame.condition == "linear"].assign(condition="pilot")
    result = run_plan(lean_plan, MetricTable(frame=pd.concat([frame, extra]), source="synthetic"))
    notes = list(result.tables["notes"]["note"])
    assert any("condition 'pilot' is in the data but not in the plan" in n for n in notes)


@pytest.mark.parametrize("method", ["holm", "bonferroni", "bh"])
def test_p_adjustment_matches_statsmodels(method):
    from statsmodels.stats.multitest import multipletests

    p = np.array([0.01, 0.04, 0.03, 0.2, np.nan, 0.001])
    ours = adjust_pvalues(p, method)
    ok = ~np.isnan(p)
    ref = multipletests(p[ok], method={"holm": "holm", "bonferroni": "bonferroni", "bh": "fdr_bh"}[method])[1]
    np.testing.assert_allclose(ours[ok], ref, rtol=1e-12)
    assert np.isnan(ours[~ok]).all()
