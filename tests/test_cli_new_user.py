"""Mistakes a new user makes at the command line: each is one ``Error:`` line, before anything is shown or
written (found by following README as a study coordinator)."""

from __future__ import annotations

from studyctl.cli.app import main


def _error_only(err: str) -> list[str]:
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines and lines[-1].startswith("Error:"), err
    return lines


def test_simulate_sqlite_db_is_refused_before_the_progress_bar(tmp_path, capsys):
    out = tmp_path / "w"
    assert main(["simulate", "needle_insertion", "-n", "1", "-s", "1", "-o", str(out), "--db", "s.db"]) != 0
    err = capsys.readouterr().err
    lines = _error_only(err)
    assert lines == [lines[-1]], err  # no progress bar, no population line before it
    assert "PostgreSQL URL" in lines[-1] and "leave --db out" in lines[-1]
    assert not out.exists()


def test_simulate_into_an_existing_study_is_refused_before_the_progress_bar(tmp_path, capsys):
    out = tmp_path / "w"
    assert main(["init", str(out)]) == 0
    capsys.readouterr()
    assert main(["simulate", "needle_insertion", "-n", "1", "-s", "1", "-o", str(out)]) != 0
    err = capsys.readouterr().err
    lines = _error_only(err)
    assert lines == [lines[-1]], err
    assert "already holds a study" in lines[-1]


def test_power_defaults_to_the_shipped_plan_of_a_shipped_protocol():
    from studyctl.analysis import load_plan
    from studyctl.power import prepare_power

    spec = prepare_power("needle_insertion", sizes="5", replicates=1)
    assert spec.plan == load_plan("needle_insertion")


def test_power_without_plan_for_an_own_protocol_file_names_the_fix(tmp_path, capsys):
    import shutil

    from studyctl.protocol import resolve_protocol

    own = tmp_path / "needle_insertion.yaml"  # same name as a shipped protocol, but the user's own file
    shutil.copy(resolve_protocol("needle_insertion"), own)
    assert main(["power", str(own), "-n", "5", "-r", "1", "-o", str(tmp_path / "pw")]) != 0
    lines = _error_only(capsys.readouterr().err)
    assert "--plan is needed" in lines[-1] and "give --plan FILE" in lines[-1] and "needle_insertion" in lines[-1]
    assert not (tmp_path / "pw").exists()


def test_power_help_says_the_plan_default(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "400")  # one line per option: the phrase is not cut by the help box
    assert main(["power", "--help"]) == 0
    assert "the shipped plan of the same name" in " ".join(capsys.readouterr().out.split())


NEGATIVE_SCANS = """\
format: studyctl-targets/1
protocol: needle_insertion
source: "a typo"
targets:
  - id: scans_bl_mean
    metric: scans
    where: {condition: BL}
    statistic: {stat}
    value: -3
    role: fit
  - id: scans_verdict
    metric: scans
    statistic: verdict
    test: scans_anova
    value: true
    role: validation
"""


def test_targets_refuse_a_negative_mean_of_a_count_but_not_a_negative_change(tmp_path):
    import pytest

    from studyctl.errors import PopulationError
    from studyctl.populations.targets import load_targets_file

    bad = tmp_path / "neg.targets.yaml"
    bad.write_text(NEGATIVE_SCANS.replace("{stat}", "mean"))
    with pytest.raises(PopulationError) as exc:
        load_targets_file(bad)
    assert str(exc.value).startswith(f"{bad}:9:") and "'scans'" in str(exc.value)
    assert "cannot be below 0, got -3" in str(exc.value)
    ok = tmp_path / "change.targets.yaml"  # a percent change of a count may well be negative
    ok.write_text(NEGATIVE_SCANS.replace("{stat}", "pct_change_vs_baseline").replace("{condition: BL}",
                                                                                      "{condition: ES}"))
    assert load_targets_file(ok).get("scans_bl_mean").value == -3


def test_calibrate_refuses_a_negative_duration_before_any_fit(tmp_path, capsys):
    bad = tmp_path / "neg.targets.yaml"
    bad.write_text(NEGATIVE_SCANS.replace("{stat}", "median").replace("metric: scans\n    where",
                                                                      "metric: duration\n    where", 1))
    out = tmp_path / "cal.yaml"
    assert main(["calibrate", "needle_insertion", "--targets", str(bad), "-o", str(out)]) != 0
    lines = _error_only(capsys.readouterr().err)
    assert lines == [lines[-1]] and "'duration' (Duration, s) cannot be below 0" in lines[-1]
    assert list(tmp_path.iterdir()) == [bad]  # no journal, no population written


def test_a_folder_or_device_given_as_protocol_says_so(tmp_path, capsys):
    assert main(["protocol", "check", str(tmp_path)]) != 0
    line = _error_only(capsys.readouterr().err)[-1]
    assert "is a folder, not a file" in line and "YAML file" in line  # was: "no file ... and no shipped protocol"
    assert main(["init", str(tmp_path / "ws"), "--protocol", "/dev/null"]) != 0
    line = _error_only(capsys.readouterr().err)[-1]
    assert "not a regular file" in line and not (tmp_path / "ws").exists()


def test_report_with_a_plan_that_is_not_yaml_leaves_no_folder(tmp_path, capsys):
    plan = tmp_path / "plan.yaml"
    plan.write_text("a: [\n")
    out = tmp_path / "rep"
    assert main(["report", str(plan), "-o", str(out), "--db", str(tmp_path / "none.db")]) != 0
    line = _error_only(capsys.readouterr().err)[-1]
    assert "plan.yaml:2:1: YAML syntax error" in line
    assert not out.exists()


def test_targets_file_that_is_binary_or_a_folder_is_one_error(tmp_path, capsys):
    binary = tmp_path / "t.yaml"
    binary.write_bytes(b"format: x\n\xd0\xff\n")
    for bad, says in ((binary, "t.yaml:2: targets file"), (tmp_path, "is a folder")):
        assert main(["calibrate", "data_driven_palpation", "--targets", str(bad), "-o", str(tmp_path / "c.yaml")]) != 0
        line = _error_only(capsys.readouterr().err)[-1]
        assert says in line, line
    assert not (tmp_path / "c.yaml").exists() and not (tmp_path / "c.yaml.journal").exists()


def test_answers_file_that_is_a_folder_says_so(tmp_path):
    import pytest

    from studyctl.engine.ui import Script
    from studyctl.errors import UsageError

    with pytest.raises(UsageError, match="is a folder"):
        Script.load(tmp_path)


def test_device_check_rate_zero_is_refused_not_the_default(capsys):
    assert main(["device", "check", "sim_palpation", "--rate", "0"]) != 0
    lines = _error_only(capsys.readouterr().err)
    assert lines == [lines[-1]] and "--rate must be between 1 and 10000 Hz, got 0" in lines[-1]
