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
