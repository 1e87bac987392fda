"""``studyctl bench power``'s two-stage figures, measured on the small test study (the bench itself uses seed 000)."""

from __future__ import annotations

import math

import pytest
from power_testdata import PLAN, PROTOCOL, SEED

from studyctl.bench.power import two_stage_figures


@pytest.mark.slow  # an 84-person pool through the engine: minutes on this machine
def test_two_stage_figures_are_measured_and_consistent():
    figures, rows, notes = two_stage_figures(True, protocol=PROTOCOL, plan=PLAN, n=4, seed=SEED)
    assert figures["two_stage_pool_people"] >= 80  # 20 × n, in chunks of whole blocks
    assert figures["two_stage_pool_build_s"] > 0 and figures["two_stage_replicates_per_s_stage2_4"] > 0
    assert figures["power_error_exact_replicates"] == 2 and figures["power_error_two_stage_replicates"] == 20
    err = figures["power_error_pp"]
    assert not math.isnan(err) and 0 <= err <= 100
    assert figures["power_error_mc_se_two_stage_pp_max"] <= 50 / math.sqrt(20) + 1e-9  # binomial SE bound
    assert [r["backend"] for r in rows][1].startswith("two-stage stage 2") and "not a validation" in notes[0]
