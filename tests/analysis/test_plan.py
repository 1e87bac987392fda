"""The analysis-plan language: the shipped plans load; every kind of mistake gets file:line and a fix."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from studyctl.analysis.plan import check_plan, load_plan
from studyctl.errors import NotFoundError, ProtocolError
from studyctl.resources import shipped_names

REFERENCE = ["bio_inspired_palpation", "needle_insertion", "data_driven_palpation", "pseudo_haptic_palpation"]

MINIMAL = """\
version: 1
study: my_study
title: t
conditions: [a, b]
groups: [g1, g2]
metrics:
  time: {metric: completion_time}
tests:
  - id: t1
    test: rank_sum
    metrics: [time]
    compare: condition
"""


def write(tmp_path: Path, text: str, name: str = "plan.yaml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return p


def problems_of(tmp_path: Path, text: str) -> list[str]:
    with pytest.raises(ProtocolError) as info:
        load_plan(write(tmp_path, text))
    return info.value.problems


@pytest.mark.parametrize("name", REFERENCE)
def test_reference_plans_load_and_match_their_protocols(name):
    from studyctl.protocol import load_protocol, resolve_protocol

    plan = load_plan(name)
    protocol = load_protocol(resolve_protocol(name))
    assert plan.study == name
    assert set(plan.condition_ids) == set(protocol.condition_ids)
    roles = {t.role for t in plan.tests}
    assert "paper" in roles and "within_subject" in roles


def test_every_shipped_plan_is_valid():
    names = shipped_names("analysis")
    assert set(REFERENCE) <= set(names)
    for name in names:
        assert check_plan(name) == [], name


def test_minimal_plan(tmp_path):
    plan = load_plan(write(tmp_path, MINIMAL))
    assert plan.condition_ids == ["a", "b"]
    assert plan.metric_name("time") == "completion_time"
    assert plan.metric_unit("time") == "s"
    assert plan.tests[0].role == "paper"


def test_unknown_top_level_key_suggests_nearest(tmp_path):
    (msg,) = problems_of(tmp_path, MINIMAL + "alpah: 0.01\n")
    assert msg.startswith(f"{tmp_path / 'plan.yaml'}:13:1: alpah: unknown key 'alpah'; did you mean 'alpha'?")


def test_unknown_nested_key_points_at_its_line(tmp_path):
    text = MINIMAL.replace("    compare: condition\n", "    compare: condition\n    posthok: {test: dunn}\n")
    (msg,) = problems_of(tmp_path, text)
    assert ":13:5: tests[0].posthok: unknown key 'posthok'; did you mean 'posthoc'?" in msg


def test_unknown_metric_test_and_condition_named_with_suggestions(tmp_path):
    text = MINIMAL.replace("completion_time", "completion_tme").replace("test: rank_sum", "test: rank_summ")
    text = text.replace("compare: condition", "compare: condition\n    levels: [a, bb]")
    msgs = problems_of(tmp_path, text)
    joined = "\n".join(msgs)
    assert ":7:10: metrics.time.metric: unknown metric 'completion_tme'; did you mean 'completion_time'?" in joined
    assert "tests[0].test: unknown test 'rank_summ'; did you mean 'rank_sum'?" in joined
    # an unknown test stops the checks of that entry; the level check runs for known tests
    text2 = MINIMAL.replace("compare: condition", "compare: condition\n    levels: [a, bb]")
    (msg,) = problems_of(tmp_path, text2)
    assert "tests[0].levels[1]: unknown condition 'bb'" in msg and "allowed: a, b" in msg


def test_test_referencing_undeclared_metric(tmp_path):
    (msg,) = problems_of(tmp_path, MINIMAL.replace("metrics: [time]", "metrics: [tiem]"))
    assert "tests[0].metrics[0]: unknown metric 'tiem'; did you mean 'time'?" in msg
    # suggestions ignore case, as in protocol files
    (msg,) = problems_of(tmp_path, MINIMAL.replace("metrics: [time]", "metrics: [TIME]"))
    assert "tests[0].metrics[0]: unknown metric 'TIME'; did you mean 'time'?" in msg


def test_wrong_types_and_values(tmp_path):
    text = MINIMAL.replace("study: my_study", "study: my_study\nalpha: 1.5\nmissing: drop")
    msgs = problems_of(tmp_path, text)
    joined = "\n".join(msgs)
    assert "alpha: alpha must be between 0 and 1 (exclusive), found 1.5" in joined
    assert "missing: Input should be 'available', 'complete_cases' or 'fail'" in joined


def test_option_checks(tmp_path):
    text = MINIMAL.replace("compare: condition", "compare: condition\n    options: {alternativ: less, method: exactly}")
    msgs = "\n".join(problems_of(tmp_path, text))
    assert "rank_sum has no option 'alternativ'; did you mean 'alternative'?" in msgs
    assert "method must be one of auto, exact, asymptotic, found 'exactly'; did you mean 'exact'?" in msgs


def test_within_subject_test_cannot_compare_groups(tmp_path):
    text = MINIMAL.replace("test: rank_sum", "test: friedman").replace("compare: condition", "compare: group")
    (msg,) = problems_of(tmp_path, text)
    assert "friedman pairs values by participant, so it cannot compare groups" in msg


def test_duplicate_keys_and_ids(tmp_path):
    text = MINIMAL + "  - id: t1\n    test: rank_sum\n    metrics: [time]\n"
    (msg,) = problems_of(tmp_path, text)
    assert "tests[1]: duplicate id 't1'" in msg
    with pytest.raises(ProtocolError, match=r"plan.yaml:4:1: title: duplicate key 'title' \(the first is on line 3\)"):
        load_plan(write(tmp_path, MINIMAL.replace("title: t\n", "title: t\ntitle: u\n")))


def test_yaml_syntax_error_has_line_and_column(tmp_path):
    with pytest.raises(ProtocolError, match=r"plan.yaml:4:\d+: YAML syntax error"):
        load_plan(write(tmp_path, "version: 1\nstudy: s\ntitle: [unclosed\nconditions: [a\n"))


def test_conditions_checked_against_shipped_protocol(tmp_path):
    text = MINIMAL.replace("study: my_study", "study: needle_insertion").replace("[a, b]", "[BL, RTT]")
    text = text.replace("groups: [g1, g2]", "groups: [all]")
    (msg,) = problems_of(tmp_path, text)
    assert "conditions[1]: protocol 'needle_insertion' has no condition 'RTT'; did you mean 'RT'?" in msg


def test_figure_references_checked(tmp_path):
    text = (
        MINIMAL.replace("id: t1", "id: groups")
        + "figures:\n  - {id: f, kind: boxplot, metrics: [time], marks: grups}\n"
    )
    msgs = "\n".join(problems_of(tmp_path, text))
    assert "figures[0].kind: unknown figure kind 'boxplot'; did you mean 'box'?" in msgs
    assert "figures[0].marks: unknown test id 'grups'; did you mean 'groups'?" in msgs


def test_csv_source_needs_an_existing_file(tmp_path):
    text = MINIMAL.replace("study: my_study", "study: my_study\ndata: {source: csv, path: nowhere.csv}")
    (msg,) = problems_of(tmp_path, text)
    assert "data.path: no such file" in msg and "nowhere.csv" in msg


def test_missing_plan_file_and_unknown_name():
    with pytest.raises(NotFoundError, match="no shipped analysis plan of that name; shipped: bio_inspired"):
        load_plan("no_such_plan")


def test_empty_and_non_mapping_files(tmp_path):
    with pytest.raises(ProtocolError, match="the file is empty"):
        load_plan(write(tmp_path, ""))
    with pytest.raises(ProtocolError, match="an analysis plan is a YAML mapping, found list"):
        load_plan(write(tmp_path, "- a\n- b\n"))


def test_every_problem_is_reported_at_once(tmp_path):
    text = MINIMAL.replace("alpha", "x") + "alpah: 1\nfigurs: []\n"
    msgs = problems_of(tmp_path, text)
    assert len(msgs) == 2


def test_a_plan_name_where_a_loaded_plan_is_needed_is_one_clear_error(tmp_path):
    from studyctl.analysis.run import analyze
    from studyctl.errors import StudyctlError
    from studyctl.workflows.report import build_report

    with pytest.raises(StudyctlError, match=r"analyze takes a loaded plan.*load_plan\('needle_insertion'\)"):
        analyze("needle_insertion")
    with pytest.raises(StudyctlError, match=r"build_report takes a loaded plan"):
        build_report("needle_insertion", tmp_path / "out")
    assert not (tmp_path / "out").exists()
