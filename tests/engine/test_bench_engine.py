"""`studyctl bench engine` runs and reports its figures (a smoke run: timings are not asserted)."""

from __future__ import annotations

import json

from studyctl.cli.app import main


def test_bench_engine_quick_json(capsys):
    assert main(["bench", "engine", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    figures = out["figures"]
    for key in ("virtual_trials_per_s", "virtual_trials_per_cpu_s", "event_commit_ms_p99", "event_commit_ms_p50"):
        assert figures[key] > 0
    assert figures["event_commit_ms_p99"] >= figures["event_commit_ms_p50"]
    variants = [row["variant"] for row in next(iter(out["tables"].values()))]
    assert variants[0].startswith("engine + SQLite store")
