"""The analysis commands end to end: CSV plans, study databases, and every bad input as one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from studyctl.analysis import analyze, load_plan
from studyctl.cli.app import main
from studyctl.errors import AnalysisError


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_analyze_check_only(capsys):
    code, out, _ = run(capsys, "analyze", "needle_insertion", "--check")
    assert code == 0 and out.strip().endswith("OK (6 metrics, 10 tests, 4 figures)")


def test_analyze_csv_plan_prints_tests(capsys):
    code, out, err = run(capsys, "analyze", "pseudo_haptic_palpation_published", "--json")
    assert code == 0, err
    rows = json.loads(out)
    assert {r["test_id"] for r in rows} == {"sensitivity_wilson", "sensitivity_pairs"}
    assert len(rows) == 4 + 6


@pytest.mark.slow
def test_report_csv_plan(capsys, tmp_path):
    code, out, err = run(capsys, "report", "pseudo_haptic_palpation_published", "--out", str(tmp_path / "r"))
    assert code == 0, err
    assert f"Report: {tmp_path / 'r' / 'report.html'}" in out
    assert (tmp_path / "r" / "figures" / "fig5b_sensitivity.png").is_file()
    code, out, err = run(capsys, "report", "pseudo_haptic_palpation_published", "--out", str(tmp_path / "j"),
                         "--figure-format", "svg", "--json")
    assert code == 0, err
    files = json.loads(out)  # stdout is the one object: the progress spinner goes to stderr
    assert files["html"] == str(tmp_path / "j" / "report.html") and files["partial"] is False
    assert any(f.endswith(".svg") for f in files["figures"]) and all(Path(f).is_file() for f in files["figures"])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["analyze", "no_such_plan"], "Error: no file 'no_such_plan' and no shipped analysis plan of that name"),
        (
            ["report", "pseudo_haptic_palpation_published", "--out", "/dev/null/x"],
            "Error: cannot write the report to '/dev/null/x'",
        ),
        (["analyze", "pseudo_haptic_palpation_published", "--db", "sqlite:///x.db"], "Error: plan "),
        (
            ["simulate", "bio_inspired_palpation", "--participants", "0", "--seed", "1"],
            "Error: --participants must be at least 1, got 0",
        ),
        (
            ["simulate", "data_driven_palpation", "-n", "1", "-s", "1", "-o", "/tmp/never-made", "--sim-rate-hz", "0"],
            "Error: --sim-rate-hz (the simulation loop rate) must be a positive number of Hz, got 0.0",
        ),
        (
            ["demo", "--out", "/tmp/never-made", "--sim-rate-hz", "-5"],
            "Error: --sim-rate-hz (the simulation loop rate) must be a positive number of Hz, got -5.0",
        ),
    ],
)
def test_bad_input_is_one_line(capsys, args, message):
    code, _, err = run(capsys, *args)
    assert code != 0
    assert err.startswith(message), err
    assert "Traceback" not in err


def test_plan_with_problems_lists_them(capsys, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: 1\nstudy: s\ntitle: t\nconditions: [a]\nmetrics: {x: {metric: scan}}\ntests: []\n")
    code, _, err = run(capsys, "analyze", str(bad), "--check")
    assert code != 0
    assert "bad.yaml:5:15: metrics.x.metric: unknown metric 'scan'; did you mean 'scans'?" in err


def test_study_without_completed_trials(tmp_path, capsys):
    from studyctl.store.workspace import init_workspace

    init_workspace(tmp_path / "ws", protocol="bio_inspired_palpation", seed=1)
    with pytest.raises(AnalysisError, match=r"study 'bio_inspired_palpation' has no completed trials .*run sessions"):
        analyze(load_plan("bio_inspired_palpation"), workspace=tmp_path / "ws")
    code, _, err = run(capsys, "analyze", "bio_inspired_palpation", "--workspace", str(tmp_path / "ws"))
    assert code != 0 and err.startswith("Error: study 'bio_inspired_palpation' has no completed trials")


def test_plan_for_another_protocol_is_refused(tmp_path):
    from studyctl.store.workspace import init_workspace

    init_workspace(tmp_path / "ws", protocol="bio_inspired_palpation", seed=1)
    with pytest.raises(
        AnalysisError,
        match="analyses protocol 'needle_insertion', but study 'bio_inspired_palpation'"
        " ran protocol 'bio_inspired_palpation'",
    ):
        analyze(load_plan("needle_insertion"), workspace=tmp_path / "ws")


def test_piped_tables_are_whole(capsys, monkeypatch):
    # stdout is not a terminal here: rich would assume 80 columns and cut notes and wrap comparisons
    monkeypatch.delenv("COLUMNS", raising=False)
    code, out, err = run(capsys, "analyze", "pseudo_haptic_palpation_published")
    assert code == 0, err
    assert "equal proportions: no margin towards zero (the paper prints NULL)" in out
    assert any(line.startswith("sensitivity manual vs PHF_FF ") for line in out.splitlines())
    assert "…" not in out


@pytest.mark.slow
def test_simulate_of_own_protocol_file_does_not_suggest_a_plan_that_does_not_exist(tmp_path, capsys):
    from studyctl.resources import resource_dir

    own = tmp_path / "my_palpation.yaml"
    own.write_text((resource_dir("protocols") / "data_driven_palpation.yaml").read_text())
    code, out, err = run(capsys, "simulate", str(own), "-n", "1", "-s", "1", "-o", str(tmp_path / "ws"))
    assert code == 0, err
    nxt = next(line for line in out.splitlines() if "next:" in line)
    assert "studyctl report PLAN.yaml --workspace" in nxt and "my_palpation" not in nxt
    assert "no shipped analysis plan is named 'my_palpation'" in out and "data_driven_palpation" in out


@pytest.mark.parametrize(("protocol", "line"), [
    # seed 000: 50 Hz controllers, not rate-adjustable: the cap slows nothing, and the run says so (it ran silently)
    ("bio_inspired_palpation", "loop rates: no_feedback, piecewise, linear, bio_inspired 50 Hz (the protocol's rates)"),
    ("data_driven_palpation", "loop rates: haptic 250 Hz (rate-adjustable loops capped at 250 Hz; leave --sim-rate-hz "
                              "out for the protocol's rates)"),
])
def test_simulate_says_what_its_rate_cap_did_in_powers_words(tmp_path, capsys, protocol, line):
    code, out, err = run(capsys, "simulate", protocol, "-n", "1", "-s", "1", "-o", str(tmp_path / "ws"),
                         "--sim-rate-hz", "250")
    assert code == 0, err
    assert line in err.splitlines() and "loop rates" not in out
