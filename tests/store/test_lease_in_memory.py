"""No lease heartbeat thread on an in-memory SQLite database (its own connection would see another, empty
database; a power analysis's simulated studies live in such databases, also on Dask worker threads)."""

from __future__ import annotations

from studyctl.store.db import Database
from studyctl.store.lease import SessionLeaseHandle


def test_heartbeat_only_for_databases_other_processes_can_open(tmp_path):
    memory = SessionLeaseHandle(Database.create("sqlite://"), 1, "t", None)
    memory.start_heartbeat(0.01)
    assert memory._thread is None
    on_disk = SessionLeaseHandle(Database.create(f"sqlite:///{tmp_path / 'study.sqlite'}"), 1, "t", None)
    on_disk.start_heartbeat(0.01)
    try:
        assert on_disk._thread is not None and on_disk._thread.is_alive()
    finally:
        on_disk._stop.set()
        on_disk._thread.join(timeout=5)
