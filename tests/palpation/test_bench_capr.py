"""``studyctl bench capr --json`` runs and reports its figures (a smoke run: no timing is asserted)."""

from __future__ import annotations

import json

from studyctl.cli.app import main


def test_bench_capr_json(capsys):
    assert main(["bench", "capr", "--quick", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    fig = data["figures"]
    for key in ("full_realtime_factor", "full_realtime_factor_batch", "reduced_within_1pct_realtime_factor",
                "reduced_within_1pct_command_error_pct", "speedup_vs_reference", "speedup_vs_peer"):
        assert fig[key] > 0, key
    assert fig["full_units"] == 539 and fig["reference_update_ms"] == 42.0
    assert data["peers"]["full_update_us"] > fig["full_update_us"]
    rows = {r["variant"]: r for r in data["tables"]["variants"]}
    assert rows["full"]["command_error_pct"] == 0.0
    assert rows["contact only"]["units"] < rows["full"]["units"]
    assert rows["one unit per type"]["units"] == 3 and rows["one unit per type"]["command_error_pct"] > 1.0
    assert fig["reduced_within_1pct_command_error_pct"] <= 1.0
