"""The loop-rate line: one formatter in report/, used by every command that says at which rates it simulated."""

from __future__ import annotations

import re
from pathlib import Path

import studyctl
from studyctl.report.loop_rates import loop_rates_line


def test_conditions_sharing_a_rate_are_listed_together_in_order():
    rates = {"BL": 250.0, "RT": 250.0, "ES": 1000.0, "EG": 250.0}
    assert loop_rates_line(rates, 250.0) == ("loop rates: BL, RT, EG 250 Hz; ES 1000 Hz (rate-adjustable loops capped "
                                             "at 250 Hz; --full-rate for the protocol's rates)")


def test_protocol_rates_and_a_study_without_a_loop():
    assert loop_rates_line({"no_feedback": 50.0, "linear": 50.0}, None) == (
        "loop rates: no_feedback, linear 50 Hz (the protocol's rates)")
    assert loop_rates_line({}, None) == "loop rates: no feedback loop (the protocol's rates)"
    assert loop_rates_line({"haptic": 437.5}, 437.5).startswith("loop rates: haptic 437.5 Hz (rate-adjustable loops "
                                                                 "capped at 437.5 Hz;")


def test_a_command_without_full_rate_names_its_own_way_back():
    assert loop_rates_line({"haptic": 250.0}, 250.0, undo="leave --sim-rate-hz out") == (
        "loop rates: haptic 250 Hz (rate-adjustable loops capped at 250 Hz; leave --sim-rate-hz out for the protocol's "
        "rates)")
    assert loop_rates_line({"haptic": 50.0}, None, undo="x").endswith("(the protocol's rates)")


def test_no_module_outside_report_writes_the_loop_rate_line_itself():
    """Formatting lives in report/: a second 'loop rates: ...' f-string elsewhere would drift from this one."""
    root = Path(studyctl.__file__).parent
    pattern = re.compile(r"""f["'](simulated )?loop rates: """)
    found = [str(p.relative_to(root)) for p in sorted(root.rglob("*.py"))
             if p.parent.name != "report" and pattern.search(p.read_text(encoding="utf-8"))]
    assert found == []
