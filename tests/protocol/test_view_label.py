"""A condition's view_label is what the participant's screen calls it: never a condition's own name."""

from __future__ import annotations

from studyctl.protocol import check_protocol, load_protocol


def test_protocol_check_refuses_a_view_label_that_names_a_condition(write, valid_text):
    text = valid_text.replace("{id: A, controller: none}", "{id: A, controller: none, view_label: b}")
    problems = [str(p) for p in check_protocol(write(text))]
    assert len(problems) == 1 and "conditions[0].view_label: view label names a condition" in problems[0]
    ok = valid_text.replace("{id: A, controller: none}", "{id: A, controller: none, view_label: Session 1}")
    assert load_protocol(write(ok)).conditions[0].view_label == "Session 1"
