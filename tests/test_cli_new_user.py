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
