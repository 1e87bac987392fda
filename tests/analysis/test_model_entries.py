"""The model tests as plan entries: group × condition through the runner, Likert items as ordinal data, a
design that cannot be fitted as a flagged row, and plan mistakes at file:line."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from studyctl.analysis import MetricTable, load_plan, run_plan
from studyctl.errors import StudyctlError

PLAN = """\
version: 1
study: toy
title: Toy
conditions: [A, B, C]
groups: [novice, expert]
metrics:
  force: {metric: mean_contact_force}
  score: {metric: likert}
tests:
  - id: art
    test: art_anova
    metrics: [force]
    compare: condition
    options: {factor: group}
  - id: lmm
    test: mixed_model
    metrics: [force]
    compare: condition
    options: {factor: group}
  - id: ord
    test: ordinal
    metrics: [score]
    compare: condition
    by: [item]
"""


def _table(rng: np.random.Generator, *, drop_expert_c: bool = False) -> pd.DataFrame:
    rows = []
    for i in range(14):
        group = "novice" if i < 8 else "expert"
        u = rng.normal(0, 0.4)
        for k, c in enumerate("ABC"):
            if drop_expert_c and group == "expert" and c == "C":
                continue
            base = {"participant": f"P{i:02d}", "group": group, "condition": c, "trial": f"{i}{c}",
                    "repetition": 1, "denominator": np.nan}
            rows.append({**base, "metric": "mean_contact_force", "level": None,
                         "value": 3 + u + 0.5 * k + 0.3 * (group == "expert") + rng.gamma(2, 0.2)})
            for item in ("easy", "confident"):
                rows.append({**base, "metric": "likert", "level": item, "value": float(rng.integers(1, 6))})
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    path = tmp_path_factory.mktemp("plan") / "plan.yaml"
    path.write_text(PLAN)
    return load_plan(path)


def test_model_rows_one_per_term(plan):
    frame = run_plan(plan, MetricTable(frame=_table(np.random.default_rng(3)), source="toy")).to_frame()
    art = frame[frame.test_id == "art"]
    assert list(art.groups) == ["group", "condition", "group × condition"]
    assert set(art.status) == {"ok"} and art.p.notna().all()
    assert list(art.statistic_name) == ["chi2 (LR)"] * 3  # repeated participants: random-intercept LR test
    cond = art[art.groups == "condition"].iloc[0]
    assert cond.df == 2 and cond.p < 0.05 and cond.n == 42
    lmm = frame[frame.test_id == "lmm"]
    assert list(lmm.groups) == ["group", "condition", "group × condition"] and lmm.p.notna().all()
    ordinal = frame[frame.test_id == "ord"]
    assert list(ordinal.split) == ["item=easy", "item=confident"] and list(ordinal.df) == [2, 2]
    assert ordinal.effect_size_name.eq("nagelkerke_r2").all()


def _one_group(t: pd.DataFrame) -> pd.DataFrame:
    return t[t.group == "novice"]


def _one_person_per_group(t: pd.DataFrame) -> pd.DataFrame:
    return t[t.participant.isin(["P00", "P08"])]


def _constant_force(t: pd.DataFrame) -> pd.DataFrame:
    return t.assign(value=np.where(t.metric == "mean_contact_force", 2.5, t.value))


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        (None, "singular"),                       # no expert in condition C: an empty cell
        (_one_group, "factor group has one level"),
        (_one_person_per_group, "no replication"),
        (_constant_force, "does not vary"),
    ],
)
def test_a_design_it_cannot_fit_is_a_flagged_row(plan, change, reason):
    table = _table(np.random.default_rng(3), drop_expert_c=change is None)
    frame = run_plan(plan, MetricTable(frame=change(table) if change else table, source="toy")).to_frame()
    for test_id in ("art", "lmm"):
        rows = frame[frame.test_id == test_id]
        assert len(rows) == 3 and set(rows.status) == {"not_computed"}, (test_id, rows.status.tolist())
        assert rows.warnings.str.contains(reason).all(), rows.warnings.tolist()
        assert rows.p.isna().all() and rows.significant.isna().all()


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("options: {factor: group}\n  - id: lmm", "options: {factor: grup}\n  - id: lmm",
         "plan.yaml:14:15: tests[0].options.factor: unknown factor 'grup'; did you mean 'group'?"),
        ("options: {factor: group}\n  - id: lmm", "options: {factor: condition}\n  - id: lmm",
         "plan.yaml:14:15: tests[0].options.factor: the second factor 'condition' is already compared"),
        ("test: ordinal", "test: ordinl",
         "plan.yaml:21:5: tests[2].test: unknown test 'ordinl'; did you mean 'ordinal'?"),
    ],
)
def test_plan_mistakes_name_file_and_line(tmp_path, old, new, message):
    path = tmp_path / "plan.yaml"
    assert old in PLAN
    path.write_text(PLAN.replace(old, new, 1))
    with pytest.raises(StudyctlError) as err:
        load_plan(path)
    assert message in str(err.value), str(err.value)


def test_model_coefficients_with_intervals_for_the_report(plan):
    from studyctl.analysis.model_ci import model_coefficient_intervals
    from studyctl.report.document import markdown
    from studyctl.stats.model_intervals import mixed_coefficients

    result = run_plan(plan, MetricTable(frame=_table(np.random.default_rng(3)), source="toy"))
    coef = model_coefficient_intervals(result)
    lmm = coef[coef.test_id == "lmm"]
    # intercept, group[expert], condition[B], condition[C], and the two interaction columns
    assert list(lmm.coefficient) == ["(Intercept)", "group[expert]", "condition[B]", "condition[C]",
                                     "group[expert]:condition[B]", "group[expert]:condition[C]"]
    units = result.tables["units"]
    force = units[units.metric == "force"]  # the plan's metric id
    direct = mixed_coefficients(force["value"], {"group": force["group"], "condition": force["condition"]},
                                force["participant"], levels={"group": ["novice", "expert"],
                                                              "condition": ["A", "B", "C"]}).to_frame()
    assert np.allclose(lmm[["estimate", "ci_low", "ci_high"]].to_numpy(dtype=float),
                       direct[["estimate", "ci_low", "ci_high"]].to_numpy(dtype=float))
    assert (lmm.ci_low < lmm.estimate).all() and (lmm.estimate < lmm.ci_high).all()
    # the made-up data's condition effect (+0.5 per step) is inside its interval, and B > A is clear
    b = lmm[lmm.coefficient == "condition[B]"].iloc[0]
    assert b.ci_low < 0.5 < b.ci_high and b.ci_low > 0
    ordinal = coef[coef.test_id == "ord"]
    assert set(ordinal.split) == {"item=easy", "item=confident"}
    assert set(ordinal[ordinal.status == "ok"].coefficient) <= {"condition[B]", "condition[C]"}
    assert coef[coef.test_id == "art"].empty  # ART's LR rows have no coefficients to show
    from dataclasses import replace

    text = markdown(replace(result, tables={**result.tables, "model_coefficients": coef}), [], [])
    assert "Coefficients in treatment coding" in text and "group[expert]:condition[C]" in text
