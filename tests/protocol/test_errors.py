"""Bad protocol input: every error names file:line:column, the key path, what was found and what is allowed."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from studyctl.cli.app import main
from studyctl.errors import NotFoundError, ProtocolError
from studyctl.protocol import check_protocol, find_problems, load_protocol


def _problems(write, text: str) -> list[str]:
    path = write(text)
    return [str(p).replace(path, "p.yaml") for p in check_protocol(path)]


def test_valid_protocol_has_no_problems(write, valid_text):
    assert _problems(write, valid_text) == []
    protocol = load_protocol(write(valid_text))
    assert protocol.condition_ids == ("A", "B", "C", "D")
    assert len(protocol.sha256) == 64


CASES = {
    "yaml_syntax": (
        ("  title: Minimal study", "  title: [Minimal study"),
        ["p.yaml:5:10: <root>: YAML syntax error: did not find expected ',' or ']' (while parsing a flow sequence):"
         " found ': \"1\"', allowed valid YAML"],
    ),
    "unknown_key_with_suggestion": (
        ("  scheme: williams", "  shceme: williams"),
        ["p.yaml:19:3: counterbalance.scheme: missing required key: found nothing, allowed a value for 'scheme'",
         "p.yaml:19:3: counterbalance.shceme: unknown key: found 'shceme', allowed one of 'allocation', "
         "'block_size', 'conditions', 'fixed_first', 'orders', 'scheme', 'within_strata'; did you mean 'scheme'?"],
    ),
    "unknown_top_level_key": (
        ("study:\n", "studdy:\n"),
        ["p.yaml:1:1: study: missing required key: found nothing, allowed a value for 'study'",
         "p.yaml:2:1: studdy: unknown key: found 'studdy', allowed one of 'conditions', 'counterbalance', 'design',"
         " 'devices', 'instruments', 'participants', 'questionnaires', 'resume', 'scene', 'study', "
         "'studyctl_protocol', 'trial'; did you mean 'study'?"],
    ),
    "wrong_type_version_number": (
        ('  version: "1"\n  seed', "  version: 1.0\n  seed"),
        ["p.yaml:5:12: study.version: wrong type: found number 1.0, allowed a string (quote values such as 1.0, yes"
         " or 007)"],
    ),
    "wrong_type_quoted_number": (
        ("  time_limit_s: 60", '  time_limit_s: "90"'),
        ["p.yaml:21:17: trial.time_limit_s: wrong type: found string '90', allowed a number"],
    ),
    "wrong_literal_with_suggestion": (
        ("  scheme: williams", "  scheme: wiliams"),
        ["p.yaml:19:11: counterbalance.scheme: value not allowed: found 'wiliams', allowed one of 'williams', "
         "'cyclic_latin', 'explicit', 'random', 'all_permutations'; did you mean 'williams'?"],
    ),
    "duplicate_condition_id": (
        ("  - {id: D, controller: bio_inspired}", "  - {id: B, controller: bio_inspired}"),
        ["p.yaml:17:10: conditions[3].id: duplicate condition id (first defined at line 15): found 'B', allowed an "
         "id not used by another condition"],
    ),
    "duplicate_yaml_key": (
        ("  break_s: 30", "  break_s: 30\n  break_s: 20"),
        ["p.yaml:23:3: trial.break_s: duplicate key (first written at line 22): found 'break_s', allowed each key "
         "once per mapping"],
    ),
    "undefined_condition": (
        ("  scheme: williams", "  scheme: williams\n  fixed_first: [E]"),
        ["p.yaml:20:17: counterbalance.fixed_first[0]: undefined condition: found 'E', allowed one of 'A', 'B', "
         "'C', 'D' (the condition ids defined in this file)"],
    ),
    "undefined_instrument": (
        ("{instrument: likert,", "{instrument: likret,"),
        ["p.yaml:34:18: questionnaires[0].instrument: undefined instrument: found 'likret', allowed 'likert' (the "
         "instrument ids defined in this file); did you mean 'likert'?"],
    ),
    "order_not_a_permutation": (
        ("  scheme: williams", "  scheme: explicit\n  orders:\n    - [A, B, C, D]\n    - [A, B, C, C]"),
        ["p.yaml:22:7: counterbalance.orders[1]: order is not a permutation of the counterbalanced conditions: "
         "found [A, B, C, C], allowed each of A, B, C, D exactly once"],
    ),
    "more_tumours_than_holes": (
        ("sites: 7,", "sites: 2,"),
        ["p.yaml:26:32: scene.placement.items: more items (tumours) than sites (holes): found 3 items in 2 sites,"
         " allowed at most 2 items"],
    ),
    "scale_with_one_point": (
        ("points: 5,", "points: 1,"),
        ["p.yaml:30:21: instruments[0].scale.points: a scale needs at least 2 points: found 1, allowed an integer"
         " >= 2"],
    ),
    "time_limit_zero": (
        ("  time_limit_s: 60", "  time_limit_s: 0"),
        ["p.yaml:21:17: trial.time_limit_s: time limit must be positive: found 0, allowed a number > 0"],
    ),
    "time_limit_negative": (
        ("  time_limit_s: 60", "  time_limit_s: -5.5"),
        ["p.yaml:21:17: trial.time_limit_s: time limit must be positive: found -5.5, allowed a number > 0"],
    ),
    "missing_key": (
        ("  title: Minimal study\n", ""),
        ["p.yaml:3:3: study.title: missing required key: found nothing, allowed a value for 'title'"],
    ),
    "unknown_controller_plugin": (
        ("controller: linear}", "controller: lienar}"),
        ["p.yaml:15:25: conditions[1].controller: unknown controller plugin: found 'lienar', allowed one of "
         "'bio_inspired', 'linear', 'needle_hybrid', 'none', 'piecewise', 'pseudo_haptic', 'pseudo_haptic_ff', "
         "'stiffness_map_ff'; did you mean 'linear'?"],
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_error_message_shape(write, valid_text, case):
    (old, new), expected = CASES[case]
    assert old in valid_text, f"test case {case} no longer matches the fixture"
    assert _problems(write, valid_text.replace(old, new, 1)) == expected


def test_check_lists_every_error_in_file_order(write, valid_text):
    text = (valid_text.replace("  time_limit_s: 60", "  time_limit_s: 0")
            .replace("sites: 7,", "sites: 2,")
            .replace("points: 5,", "points: 1,")
            .replace("  scheme: williams", "  scheme: williams\n  fixed_first: [E]")
            .replace("  - {id: D, controller: bio_inspired}", "  - {id: B, controller: bio_inspired}"))
    problems = _problems(write, text)
    assert [p.split(": ")[0] for p in problems] == ["p.yaml:17:10", "p.yaml:20:17", "p.yaml:22:17",
                                                     "p.yaml:27:32", "p.yaml:31:21"]
    path = write(text)
    with pytest.raises(ProtocolError) as info:
        load_protocol(path)
    assert len(info.value.problems) == 5
    assert str(info.value).startswith(f"{path}: 5 problems in the protocol:\n  {path}:17:10: conditions[3].id")


def test_single_problem_message_is_the_problem(write, valid_text):
    path = write(valid_text.replace("  time_limit_s: 60", "  time_limit_s: 0"))
    with pytest.raises(ProtocolError) as info:
        load_protocol(path)
    assert str(info.value) == f"{path}:21:17: trial.time_limit_s: time limit must be positive: found 0, allowed a" \
                              " number > 0"
    assert info.value.problems == [str(info.value)]
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", "p.yaml:1:1: <root>: a protocol is a mapping of sections: found an empty file, allowed a mapping "
             "starting with 'studyctl_protocol: 1'"),
        ("- a\n- b\n", "p.yaml:1:1: <root>: a protocol is a mapping of sections: found a list, allowed a mapping "
                       "starting with 'studyctl_protocol: 1'"),
    ],
)
def test_not_a_mapping(write, text, expected):
    assert _problems(write, text) == [expected]


def test_more_reference_and_feasibility_errors(write, valid_text):
    text = valid_text.replace("  scheme: williams", "  scheme: williams\n  orders: [[A, B, C, D]]\n  block_size: 3")
    text = text.replace("  - {id: A, controller: none}", "  - {id: A, manual: true, controller: none}")
    text = text.replace("anchors: {1: Strongly disagree,", "anchors: {0: Strongly disagree,")
    problems = _problems(write, text)
    assert len(problems) == 4
    joined = "\n".join(problems)
    assert "conditions[0].controller: a manual condition runs no controller: found 'none', allowed null" in joined
    assert "counterbalance.orders: orders are only used by the explicit scheme, not williams" in joined
    assert "counterbalance.block_size: block_size is only used by allocation 'blocked', not 'alternating'" in joined
    assert ("instruments[0].scale.anchors[0]: anchor code outside the scale: found 0, allowed a code from 1 to 5"
            in joined)


def test_scans_on_request_need_the_scan_request(write, valid_text):
    text = valid_text.replace("  - {id: A, controller: none}", "  - {id: A, controller: none, visual: on_request}")
    assert _problems(write, text) == [
        "p.yaml:14:39: conditions[0].visual: scans on request need the 'scan' request: found trial.requests "
        "[report, finish], allowed 'scan' listed in trial.requests"
    ]


def test_missing_file_is_not_found(tmp_path):
    with pytest.raises(NotFoundError, match="does not exist"):
        load_protocol(tmp_path / "nope.yaml")


def test_anchor_keys_and_merge_keep_positions(write, valid_text):
    text = valid_text.replace(
        "conditions:\n  - {id: A, controller: none}",
        "x-base: &base {controller: none}\nconditions:\n  - {<<: *base, id: A}",
    )
    assert _problems(write, text) == []
    text = text.replace("x-base: &base {controller: none}", "x-base: &base {controler: none}")
    problems = _problems(write, text)
    assert ("p.yaml:13:16: conditions[0].controler: unknown key: found 'controler', allowed one of "
                            "'controller', 'description', 'id', 'label', 'manual', 'params', 'view_label', 'visual'; "
                            "did you mean 'controller'?") in problems


def test_cli_check_exit_codes(write, valid_text, capsys):
    good = write(valid_text, "good.yaml")
    assert main(["protocol", "check", good]) == 0
    assert capsys.readouterr().out.startswith(f"OK: {good} is a valid protocol (mini: 4 conditions, 2 strata")
    bad = write(valid_text.replace("  time_limit_s: 60", "  time_limit_s: 0").replace("sites: 7,", "sites: 2,"),
                "bad.yaml")
    assert main(["protocol", "check", bad]) == 1
    err = capsys.readouterr().err
    assert err.splitlines() == [
        f"Error: {bad}: 2 problems in the protocol:",
        f"  {bad}:21:17: trial.time_limit_s: time limit must be positive: found 0, allowed a number > 0",
        f"  {bad}:26:32: scene.placement.items: more items (tumours) than sites (holes): found 3 items in 2 sites, "
        "allowed at most 2 items",
    ]
    assert "Traceback" not in err


_EDITS = st.sampled_from(["delete", "duplicate", "garble", "indent", "null"])


@pytest.mark.slow
@given(edit=_EDITS, line=st.integers(0, 40), junk=st.text(max_size=12))
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_any_edit_gives_problems_or_a_protocol_never_a_crash(valid_text, edit, line, junk):
    lines = valid_text.splitlines()
    i = line % len(lines)
    if edit == "delete":
        del lines[i]
    elif edit == "duplicate":
        lines.insert(i, lines[i])
    elif edit == "garble":
        lines[i] = lines[i][: len(lines[i]) // 2] + junk
    elif edit == "indent":
        lines[i] = " " + lines[i]
    else:
        head = lines[i].split(":")[0]
        lines[i] = f"{head}: null" if ":" in lines[i] else lines[i]
    text = "\n".join(lines) + "\n"
    model, problems = find_problems(text, "p.yaml")
    assert (model is None) == bool(problems)
    for problem in problems:
        message = str(problem)
        assert message.startswith(f"p.yaml:{problem.mark.line}:{problem.mark.column}: ")
        assert ": found " in message and ", allowed " in message
        assert 1 <= problem.mark.line <= len(text.splitlines()) + 1
