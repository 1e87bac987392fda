"""``studyctl bench capr --json`` runs and reports its figures (a smoke run: no timing is asserted)."""

from __future__ import annotations

import json

import pytest

from studyctl.cli.app import main


@pytest.mark.slow
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


@pytest.mark.slow
def test_read_offset_continuous_rate_against_spike_counts():
    """Our continuous-rate read is above spike counting by the 15-21 % the public code's counts show."""
    from studyctl.bench.capr import ReferenceStructure, read_offset
    from studyctl.controllers.bio_inspired import BioInspiredController

    fig = read_offset(BioInspiredController({}), ReferenceStructure({}))
    # 0.8 N plateau: ours ≈ 66.7 Hz, counted ≈ 55-57 Hz (public code 56.2-56.4, research/capr.md §7)
    assert 64 < fig["read_sa1_plateau_rate_hz"] < 69 and 53 < fig["read_sa1_plateau_spikes_hz"] < 58
    # 0.5 N/s ramp, RA1: ours ≈ 115 Hz, counted ≈ 97 Hz
    assert 110 < fig["read_ra1_ramp_rate_hz"] < 120 and 92 < fig["read_ra1_ramp_spikes_hz"] < 101
    assert 10 < fig["read_offset_sa1_plateau_pct"] < 25 and 10 < fig["read_offset_ra1_ramp_pct"] < 25
