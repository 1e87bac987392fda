"""Concurrent enrollers in separate processes never take the same slot (SQLite and PostgreSQL)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from studyctl.store import StudyStore

WORKER = Path(__file__).parent / "workers" / "enroll.py"


@pytest.mark.slow
def test_concurrent_enrollers_take_distinct_slots(db_url):
    with StudyStore.open(db_url) as store:
        study = store.create_study("s")
    procs = [subprocess.Popen([sys.executable, str(WORKER), db_url, str(study.id), "5", f"w{k}"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for k in range(3)]
    for proc in procs:
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
    with StudyStore.open(db_url) as store:
        participants = store.list_participants(study.id)
        report = store.verify_audit()
    assert sorted(p.sequence_slot for p in participants) == list(range(15))
    assert report.ok and report.rows == 16
