"""``studyctl bench power --workers 1``: serial only, no Dask cluster, the cluster figures null (a shared machine)."""

from __future__ import annotations

import json

import pytest

import studyctl.bench.power as bench_power
import studyctl.bench.power_curve as bench_curve
from studyctl.bench import BenchResult
from studyctl.cli.app import main
from studyctl.power import executor


def test_workers_1_starts_no_cluster_and_reports_null_cluster_figures(monkeypatch, capsys):
    def no_cluster(*args, **kwargs):
        raise AssertionError("--workers 1 must not start a Dask cluster")

    monkeypatch.setattr(executor.DaskBackend, "local", classmethod(no_cluster))
    # the two-stage pool (80 people) and the stored-pool curve are timed by their own tests; here only what
    # --workers changes: the serial replicate runs for real, the cluster does not
    monkeypatch.setattr(bench_power, "two_stage_figures", lambda quick: (
        {f"two_stage_exact_replicates_per_s_{bench_power.TWO_STAGE_N}": 1.0}, [], []))
    asked = []

    def curve(quick, workers=None):
        asked.append(workers)
        return BenchResult(name="power_curve", figures={})

    monkeypatch.setattr(bench_curve, "run", curve)
    assert main(["bench", "power", "--quick", "--json", "--workers", "1"]) == 0
    out = json.loads(capsys.readouterr().out)
    figures = out["figures"]
    assert figures["replicates_per_s_serial_4"] > 0 and figures["cpu_s_per_replicate_serial_4"] > 0
    for key in bench_power.cluster_keys(4, 4, 2):
        assert figures[key] is None, key
    assert figures["workers"] == 1.0
    assert "replicates_per_s_cluster_4" not in out["peers"]
    assert any("no Dask cluster started" in note for note in out["notes"])
    assert asked == [1]  # the curve's stage 2 is asked to run serially as well
    assert not any(row["backend"].startswith("local cluster") for row in out["tables"]["runs"])


def test_curve_bench_takes_workers_1_as_serial(monkeypatch, tmp_path):
    seen = []
    monkeypatch.setenv("STUDYCTL_BENCH_POOL_DIR", str(tmp_path))
    monkeypatch.setattr(bench_curve, "curve", lambda protocol, sizes, reps, folder, workers: (
        seen.append(workers) or ({}, [], [])))
    result = bench_curve.run(True, workers=1)
    assert set(seen) == {0} and "stage 2 serial in this process" in result.notes[0]


@pytest.mark.parametrize(("args", "words"), [
    (["bench", "stats", "--workers", "1"], ["--workers 1", "'stats' starts no cluster", "power"]),
    (["bench", "power", "--workers", "0"], ["--workers 0", "at least 1 worker", "--workers 1"]),
])
def test_bad_workers_is_one_error_line(args, words, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("Error:")
    assert all(word in err[0] for word in words)
