"""`studyctl init`, `status`, `db` on real folders: permissions, refusals, bad input as one clear line."""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
import stat
import subprocess
from pathlib import Path

import pytest

from studyctl.cli.app import main
from studyctl.resources import resource_dir
from studyctl.store import StudyStore
from studyctl.store.db import head_revision
from studyctl.store.identity import IdentityKey, random_code
from studyctl.store.workspace import init_workspace, load_workspace, open_study


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("Error: ") and "Traceback" not in err
    return lines[0]


def test_init_creates_private_workspace_at_head(tmp_path, capsys):
    ws = tmp_path / "study"
    code, out, err = run(capsys, "init", str(ws), "--name", "pilot", "--seed", "42")
    assert code == 0, err
    assert "Created study 'pilot'" in out
    # no temp or -wal left; the audit head file sits next to the database
    assert sorted(p.name for p in ws.iterdir()) == ["study.db", "study.db.head", "studyctl.toml"]
    for name in ("study.db", "study.db.head", "studyctl.toml"):
        assert stat.S_IMODE((ws / name).stat().st_mode) == 0o600
    assert stat.S_IMODE(ws.stat().st_mode) == 0o700
    assert load_workspace(ws).study == "pilot"
    with open_study(workspace=ws) as opened:
        assert opened.study.seed == 42 and opened.study.protocol_text is None
        assert opened.store.db.schema_state().up_to_date
    code, out, _ = run(capsys, "db", "current", "--workspace", str(ws))
    assert code == 0 and f"revision {head_revision()}" in out


def test_init_with_shipped_protocol_snapshots_its_text(tmp_path, capsys):
    name = sorted(p.stem for p in resource_dir("protocols").glob("*.yaml"))[0]
    code, out, err = run(capsys, "init", str(tmp_path / "w"), "--protocol", name)
    assert code == 0, err
    text = (resource_dir("protocols") / f"{name}.yaml").read_text(encoding="utf-8")
    with open_study(workspace=tmp_path / "w") as opened:
        assert opened.study.protocol_text == text
        assert opened.study.protocol_name == name
    assert opened.study.protocol_sha256 in out


def test_init_with_invalid_protocol_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("studyctl_protocol: 1\nstudy: [not, a, mapping]\n", encoding="utf-8")
    code, _, err = run(capsys, "init", str(tmp_path / "w"), "--protocol", str(bad))
    assert code != 0 and "bad.yaml" in err and "Traceback" not in err
    assert not (tmp_path / "w").exists()


def test_init_refuses_a_folder_holding_a_study(tmp_path, capsys):
    ws = tmp_path / "w"
    assert run(capsys, "init", str(ws))[0] == 0
    before = {p.name: p.stat().st_mtime_ns for p in ws.iterdir()}
    code, _, err = run(capsys, "init", str(ws), "--name", "other")
    assert code != 0
    assert "already holds a study" in one_error_line(err)
    assert {p.name: p.stat().st_mtime_ns for p in ws.iterdir()} == before


def test_init_into_existing_unrelated_folder_keeps_its_files(tmp_path, capsys):
    ws = tmp_path / "w"
    ws.mkdir()
    (ws / "notes.txt").write_text("mine")
    assert run(capsys, "init", str(ws))[0] == 0
    assert (ws / "notes.txt").read_text() == "mine"


@contextlib.contextmanager
def read_only(folder: Path):
    """Make ``folder`` unwritable even for root (chattr +i), or by mode bits for other users."""
    if os.geteuid() != 0:
        folder.chmod(0o500)
        try:
            yield
        finally:
            folder.chmod(0o700)
        return
    subprocess.run(["chattr", "+i", str(folder)], check=True, capture_output=True)
    try:
        yield
    finally:
        subprocess.run(["chattr", "-i", str(folder)], check=True, capture_output=True)


@pytest.mark.parametrize("where", ["folder itself", "parent folder"])
def test_init_in_read_only_place_is_one_clear_line(tmp_path, capsys, where):
    locked = tmp_path / "locked"
    locked.mkdir()
    target = locked if where == "folder itself" else locked / "new"
    with read_only(locked):
        code, _, err = run(capsys, "init", str(target))
        assert code != 0
        line = one_error_line(err)
        assert str(locked) in line and ("writable" in line or "permissions" in line)
        assert sorted(os.listdir(locked)) == []


def test_corrupted_database_is_one_clear_line(tmp_path, capsys):
    ws = tmp_path / "w"
    assert run(capsys, "init", str(ws))[0] == 0
    db = ws / "study.db"
    data = bytearray(db.read_bytes())
    data[:100] = os.urandom(100)  # wreck the header
    db.write_bytes(bytes(data))
    for command in (["status"], ["db", "current"], ["audit", "verify"], ["db", "upgrade"]):
        code, _, err = run(capsys, *command, "--workspace", str(ws))
        assert code != 0
        line = one_error_line(err)
        assert "study.db" in line and "backup" in line


@pytest.mark.slow
def test_damaged_pages_fail_db_check(tmp_path, capsys):
    ws = tmp_path / "w"
    assert run(capsys, "init", str(ws))[0] == 0
    with StudyStore.open(ws / "study.db") as store:
        study = store.get_study()
        for i in range(300):
            store.add_participant(study.id, f"P{i:04d}-" + "x" * 150)
    db = ws / "study.db"
    data = bytearray(db.read_bytes())
    page = 4096
    for offset in range(page * 3, len(data) - page, page * 2):  # scribble over every other page body
        data[offset + 200 : offset + 600] = b"\xff" * 400
    db.write_bytes(bytes(data))
    code, out, err = run(capsys, "db", "check", "--workspace", str(ws))
    assert code != 0
    assert "FAIL" in out or "not a readable" in err
    assert err.strip().splitlines()[-1].startswith("Error: ")


@pytest.mark.parametrize(
    ("url", "expect"),
    [
        ("mysql://root@localhost/x", "unsupported database 'mysql'"),
        ("postgresql+asyncpg://u@h/d", "psycopg 3"),
        ("postgresql://u@127.0.0.1:1/db", "cannot connect to PostgreSQL"),
        ("postgresql://u:secret@127.0.0.1:1/db", "cannot connect to PostgreSQL"),
        ("postgresql://u@127.0.0.1:1", "names no database"),
        ("sqlite:////nonexistent/folder/x.db", "no study database"),
    ],
)
def test_bad_database_urls_are_one_clear_line(capsys, url, expect):
    code, _, err = run(capsys, "status", "--db", url)
    assert code != 0
    line = one_error_line(err)
    assert expect in line
    assert "secret" not in line


def test_status_from_environment_and_verbatim_codes(tmp_path, capsys, monkeypatch):
    ws = tmp_path / "w"
    assert run(capsys, "init", str(ws), "--name", "s'1 [red]x[/red]")[0] == 0
    code_text = "P'01\"; DROP TABLE participant;-- [bold]b[/bold]"
    with open_study(workspace=ws) as opened:
        opened.store.add_participant(opened.study.id, code_text)
    monkeypatch.setenv("STUDYCTL_DB", str(ws / "study.db"))
    code, out, err = run(capsys, "status")
    assert code == 0, err
    assert "study:    s'1 [red]x[/red]" in out
    assert "participants: 1 (enrolled 1," in out
    code, out, _ = run(capsys, "audit", "show", "--json")
    rows = [json.loads(line) for line in out.splitlines()]
    assert code == 0 and rows[-1]["action"] == "participant.enroll" and rows[-1]["details"]["code"] == code_text


def test_no_workspace_anywhere_is_one_clear_line(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("STUDYCTL_DB", raising=False)
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, "status")
    assert code != 0 and "no study database given" in one_error_line(err)


def test_malformed_workspace_file(tmp_path, capsys):
    (tmp_path / "studyctl.toml").write_text("[study\nname = 1\n")
    code, _, err = run(capsys, "status", "--workspace", str(tmp_path))
    assert code != 0 and "studyctl.toml: not valid TOML" in one_error_line(err)


@pytest.mark.slow
def test_db_upgrade_from_empty_and_newer_revision(tmp_path, capsys):
    path = tmp_path / "x.db"
    sqlite3.connect(path).close()  # an empty SQLite file: no schema at all
    code, _, err = run(capsys, "db", "current", "--db", str(path))
    assert code != 0 and "no studyctl schema yet; run `studyctl db upgrade`" in one_error_line(err)
    code, out, err = run(capsys, "db", "upgrade", "--db", str(path))
    assert code == 0 and f"Upgraded the schema from empty to {head_revision()}" in out
    code, out, _ = run(capsys, "db", "upgrade", "--db", str(path))
    assert code == 0 and "Already at the newest" in out
    with sqlite3.connect(path) as conn:
        conn.execute("UPDATE alembic_version SET version_num = 'abc123future'")
    for command in (["status"], ["db", "upgrade"], ["db", "current"]):
        code, _, err = run(capsys, *command, "--db", str(path))
        assert code != 0
        line = one_error_line(err) if command != ["db", "current"] else err.strip().splitlines()[-1]
        assert "abc123future" in line and "newer studyctl" in line


@pytest.mark.postgres
def test_init_on_postgresql(tmp_path, capsys, pg_url):
    ws = tmp_path / "w"
    url_with_password = pg_url.replace("postgres@", "postgres:pw@")
    code, out, err = run(capsys, "init", str(ws), "--db", url_with_password, "--name", "multi-site")
    assert code == 0, err
    assert sorted(p.name for p in ws.iterdir()) == ["studyctl.toml"]
    toml = (ws / "studyctl.toml").read_text()
    assert ":pw@" not in toml and "127.0.0.1" in toml  # the password never lands in the file
    code, out, err = run(capsys, "status", "--workspace", str(ws))
    assert code == 0 and "study:    multi-site" in out
    code, _, err = run(capsys, "init", str(tmp_path / "w2"), "--db", pg_url, "--name", "multi-site")
    assert code != 0 and "already holds a study named 'multi-site'" in one_error_line(err)
    assert not (tmp_path / "w2").exists()


def test_identity_key_lives_outside_the_database(tmp_path):
    key = IdentityKey(tmp_path / "key.tsv")
    code = random_code()
    assert code.startswith("P-") and len(code) == 8
    key.add(code, "Ada Lovelace\t<ada@example.org>\nroom 4")
    assert stat.S_IMODE((tmp_path / "key.tsv").stat().st_mode) == 0o600
    assert IdentityKey(tmp_path / "key.tsv").lookup(code) == "Ada Lovelace\t<ada@example.org>\nroom 4"
    from studyctl.errors import NotFoundError, UsageError

    with pytest.raises(UsageError):
        key.add(code, "again")
    with pytest.raises(NotFoundError):
        key.lookup("P-NOPE00")


def test_participant_table_has_no_identity_columns():
    from studyctl.store.models import Participant

    columns = {c.name for c in Participant.__table__.columns}
    assert not columns & {"name", "first_name", "last_name", "email", "phone", "address", "birth_date", "contact"}


def test_init_library_result(tmp_path):
    result = init_workspace(tmp_path / "lib", name="lib-study", seed=7)
    assert result.study == "lib-study" and result.seed == 7 and result.database.endswith("study.db")


@pytest.mark.parametrize("db", ["s.db", "sqlite:///s.db", "sqlite://"])
def test_init_refuses_a_sqlite_db_option_before_creating_anything(tmp_path, capsys, db):
    # A SQLite study always lives in the workspace's own study.db; --db is for PostgreSQL only.
    ws = tmp_path / "w"
    code, _, err = run(capsys, "init", str(ws), "--db", db)
    line = one_error_line(err)
    assert code != 0 and f"--db {db}:" in line and "postgresql://" in line and "leave --db out" in line
    assert not ws.exists()
