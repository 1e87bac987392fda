"""``studyctl bench render --json`` keeps its contract (a smoke run: figures are measured, not checked)."""

from __future__ import annotations

import json

import pytest

from studyctl.cli.app import main


@pytest.mark.slow
def test_bench_render_json_contract(capsys):
    assert main(["bench", "render", "--quick", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    figures = doc["figures"]
    for key in ("render_us_median", "render_us_p99", "default_force_error_pct", "depth_max_error_mm"):
        assert key in figures and figures[key] >= 0
    assert figures["depth_max_error_mm"] < 1e-9  # the indexed depth query is exact
    assert set(doc["peers"]) == {"render_us_median", "render_us_p99"}
    rows = doc["tables"]["interpolation variants"]
    assert {(r["interpolation"], r["subsample"]) for r in rows} >= {
        (i, s) for i in ("nearest", "linear", "cubic") for s in (1, 2, 4)
    }
    assert all("force_error_pct" in r and "tick_us_median" in r for r in rows)
