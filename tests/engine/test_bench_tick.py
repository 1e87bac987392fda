"""The replay split of ``bench tick``: the replayed cohort does the same device/controller/scene work."""

from __future__ import annotations

import json

import pytest

from studyctl.bench.tick import split
from studyctl.cli.app import main


@pytest.mark.slow
def test_replay_stores_the_same_samples_and_saves_the_participants_work():
    got = split("bio_inspired_palpation", 1, 250.0)
    assert got["replay_same_samples"] == 1.0  # same inputs, same device/controller/scene outputs, bit for bit
    assert got["ticks"] > 1000
    # the participant's act costs something, and the rest of the loop is most of a tick but not all of it
    assert 0.0 < got["participant_us_per_tick"] < got["us_per_tick"]
    assert 0.0 < got["participant_share"] < 1.0
    assert got["other_us_per_tick"] + got["participant_us_per_tick"] == pytest.approx(got["us_per_tick"])
    assert 0.0 < got["outside_loop_share"] < 1.0
    assert got["max_speedup_without_participant"] > 1.0


@pytest.mark.slow
def test_quick_run_prints_the_split(capsys):
    assert main(["bench", "tick", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    rows = out["tables"]["split"]
    assert [r["protocol"] for r in rows] == ["bio_inspired_palpation", "pseudo_haptic_palpation"]
    assert all(r["replay_same_samples"] == 1.0 for r in rows)
    assert out["figures"]["participant_share_pseudo_haptic_palpation"] > 0.0
