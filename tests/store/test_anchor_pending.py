"""A process killed between its commit and the head file's update (the window test_durability's SIGKILL can hit)
leaves the database one commit ahead of the head file, at the head that commit announced beforehand: a note, not
a tampered tail. A row added beyond that announced head is still a problem."""

from __future__ import annotations

from sqlalchemy import create_engine, text

from studyctl.store import StudyStore, anchor
from studyctl.store.anchor import anchor_path, read_anchor
from studyctl.store.db import parse_url
from studyctl.store.maintenance import check_database


def _killed_after_commit(monkeypatch, url: str) -> None:
    """One more audited commit whose after-commit head update is lost, as when the process dies right there."""
    real = anchor.write_anchor
    monkeypatch.setattr(anchor, "write_anchor",
                        lambda path, head, *, pending=False: real(path, head, pending=True) if pending else None)
    with StudyStore.open(url) as store:
        study = store.get_study("s")
        store.add_participant(study.id, "P2")
    monkeypatch.setattr(anchor, "write_anchor", real)


def _study(tmp_path) -> str:
    url = f"sqlite:///{tmp_path / 'study.db'}"
    with StudyStore.create(url) as store:
        store.add_participant(store.create_study("s").id, "P1")
    return url


def test_a_commit_whose_head_update_was_lost_is_a_note(tmp_path, monkeypatch):
    url = _study(tmp_path)
    before = read_anchor(anchor_path(parse_url(url)))
    _killed_after_commit(monkeypatch, url)
    file = read_anchor(anchor_path(parse_url(url)))
    assert file.count == before.count and file.pending is not None and file.pending.count > before.count
    check = check_database(url)
    assert check.ok, check.lines()
    assert any("recorded as under way" in line for line in check.lines()), check.lines()
    with StudyStore.open(url) as store:  # the next commit brings the file up to date
        store.add_participant(store.get_study("s").id, "P3")
    assert read_anchor(anchor_path(parse_url(url))).pending is None and check_database(url).ok


def test_a_row_beyond_the_announced_head_is_still_a_problem(tmp_path, monkeypatch):
    url = _study(tmp_path)
    _killed_after_commit(monkeypatch, url)
    engine = create_engine(url)
    with engine.begin() as conn:  # a forged row appended behind studyctl's back (triggers dropped)
        for (name,) in conn.execute(text("SELECT name FROM sqlite_master WHERE type = 'trigger'")).all():
            conn.execute(text(f'DROP TRIGGER "{name}"'))
        last = conn.execute(text("SELECT id, hash FROM audit_log ORDER BY id DESC LIMIT 1")).one()
        conn.execute(text("INSERT INTO audit_log (id, at, actor, action, entity, entity_id, details, prev_hash, hash) "
                          "VALUES (:id, '2026-01-01 00:00:00', 'x', 'note', 'study', 1, '{}', :prev, :hash)"),
                     {"id": last.id + 1, "prev": last.hash, "hash": "f" * 64})
    engine.dispose()
    check = check_database(url)
    assert not check.ok and any("are not in the head file" in line for line in check.lines()), check.lines()
