"""Real Dask clusters on loopback give exactly the serial results.

One test starts a ``dask scheduler`` and a ``dask worker`` (2 worker processes) as subprocesses and runs
through ``--scheduler``; another runs the CLI with its default local cluster of worker processes.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest
from power_testdata import PLAN, PROTOCOL, SEED

from studyctl.workflows.power import run_power

pytestmark = pytest.mark.slow  # spawns processes / runs whole sessions: CI runs it, plain pytest skips it

START_TIMEOUT_S = 90


def _dask_command(*args: str) -> list[str]:
    script = Path(sys.executable).parent / "dask"
    return [str(script), *args] if script.exists() else [sys.executable, "-m", "dask", *args]


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


@pytest.fixture(scope="module")
def scheduler_address(tmp_path_factory):
    """A Dask scheduler and one ``dask worker`` with 2 single-threaded worker processes, on 127.0.0.1."""
    tmp = tmp_path_factory.mktemp("dask")
    info = tmp / "scheduler.json"
    logs = [open(tmp / name, "wb") for name in ("scheduler.log", "worker.log")]  # noqa: SIM115 - closed below
    procs = []
    try:
        procs.append(subprocess.Popen(
            _dask_command("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                          "--scheduler-file", str(info)), stdout=logs[0], stderr=subprocess.STDOUT))
        deadline = time.monotonic() + START_TIMEOUT_S
        while not info.exists() or not info.read_text(encoding="utf-8").strip():
            if procs[0].poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"dask scheduler did not start: {(tmp / 'scheduler.log').read_text(errors='replace')}")
            time.sleep(0.2)
        time.sleep(0.2)
        address = json.loads(info.read_text(encoding="utf-8"))["address"]
        procs.append(subprocess.Popen(
            _dask_command("worker", address, "--nworkers", "2", "--nthreads", "1", "--no-dashboard",
                          "--memory-limit", "2GiB", "--host", "127.0.0.1"),
            stdout=logs[1], stderr=subprocess.STDOUT))
        yield address
    finally:
        for proc in reversed(procs):
            _stop(proc)
        for log in logs:
            log.close()


def test_existing_scheduler_gives_the_serial_results(mini_spec, serial_run, scheduler_address, tmp_path):
    run = run_power(mini_spec, tmp_path, scheduler=scheduler_address, workers=2, figure=False)
    assert run.backend.startswith(f"Dask scheduler {scheduler_address}, 2 worker(s)")
    pd.testing.assert_frame_equal(run.to_frame(), serial_run.to_frame())
    # Every replicate ran in a worker process of the cluster, none here. Whether both workers got some is
    # Dask's scheduling (a busy machine may let one worker take all of a few short tasks), so not asserted.
    workers = set(run.replicates["worker"])
    assert 1 <= len(workers) <= 2 and not any(w.endswith(f":{os.getpid()}") for w in workers)


def test_cli_on_the_default_local_cluster(mini_spec, serial_run, tmp_path, capsys, monkeypatch):
    from studyctl.cli.app import main

    monkeypatch.setenv("COLUMNS", "200")
    code = main(["power", str(PROTOCOL), "--plan", str(PLAN), "--participants", "2", "--replicates", "2",
                 "--seed", str(SEED), "--workers", "2", "--memory-limit", "2GiB", "--out", str(tmp_path)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "local Dask cluster tcp://127.0.0.1:" in captured.err and "2 worker(s)" in captured.err
    assert "control_algorithm" in captured.out and "power.csv" in captured.out
    table = pd.read_csv(tmp_path / "power.csv", keep_default_na=False, na_values=[""])
    reference = serial_run.to_frame()
    reference = reference[reference["participants"] == 2].reset_index(drop=True)
    assert list(table["test_id"]) == list(reference["test_id"])
    assert table["significant"].tolist() == reference["significant"].tolist()
    pd.testing.assert_series_equal(table["effect_median"], reference["effect_median"], check_dtype=False)
    reps = pd.read_csv(tmp_path / "power_replicates.csv")
    assert not any(str(w).endswith(f":{os.getpid()}") for w in reps["worker"])
    assert replace(mini_spec, sizes=(2,)).tasks() == [(2, 0), (2, 1)]


def test_pool_chunks_on_a_scheduler_equal_the_serial_pool(scheduler_address, tmp_path):
    """Stage 1 on Dask: the pool's people and metric rows are those of a serial build."""
    from power_testdata import PLAN, PROTOCOL, SEED

    from studyctl.power import prepare_power
    from studyctl.power.executor import open_backend
    from studyctl.power.pool import build_pool

    spec = prepare_power(PROTOCOL, PLAN, sizes="12", replicates=1, seed=SEED)
    serial = build_pool(spec, tmp_path / "serial", 24)
    backend = open_backend(scheduler_address, 1, None)
    try:
        remote = build_pool(spec, tmp_path / "dask", 24, backend)
    finally:
        backend.close()
    assert remote.size == serial.size == 24 and remote.built_now == 2
    pd.testing.assert_frame_equal(remote.members, serial.members)
    key = ["participant", "condition", "trial", "metric", "level"]
    pd.testing.assert_frame_equal(remote.metrics.sort_values(key).reset_index(drop=True),
                                  serial.metrics.sort_values(key).reset_index(drop=True))


def test_stage2_batches_on_a_scheduler_equal_serial_draws(scheduler_address, tmp_path):
    """Stage 2 on Dask: batches of replicates drawn in worker processes (each loading the pool file) give the
    rows of the same replicates drawn here."""
    from studyctl.power import prepare_power
    from studyctl.power.executor import open_backend
    from studyctl.power.pool import build_pool
    from studyctl.power.twostage import Stage2, batches, draw_batch

    spec = prepare_power(PROTOCOL, PLAN, sizes="4", replicates=6, seed=SEED)
    pool = build_pool(spec, tmp_path / "pool", 12)
    here = {(r.participants, r.replicate): r.rows for r in (Stage2(spec, pool).replicate(4, i) for i in range(6))}
    got: dict = {}
    backend = open_backend(scheduler_address, 2, None)
    try:
        backend.map(draw_batch, spec, [(str(pool.path), 1, pool.chunk_size, n, a, b)
                                       for n, a, b in batches(spec.tasks(), 4)],
                    lambda rs: got.update({(r.participants, r.replicate): (r.rows, r.worker) for r in rs}),
                    tag="stage2")
    finally:
        backend.close()
    assert sorted(got) == sorted(here)
    for key, (rows, _) in got.items():  # as frames: NaN p-values of not-computed rows compare equal
        pd.testing.assert_frame_equal(pd.DataFrame(rows), pd.DataFrame(here[key]))
    assert not any(w.endswith(f":{os.getpid()}") for _, w in got.values())
