"""Simulated studies: virtual participants through the engine, reproducible from the seed."""

from __future__ import annotations

import pandas as pd
import pytest

from studyctl.analysis import analyze, load_plan
from studyctl.workflows.simulate import simulate_study


@pytest.mark.slow
def test_same_seed_same_data(tmp_path):
    tables = []
    for k in (1, 2):
        result = simulate_study("bio_inspired_palpation", 2, 5, tmp_path / f"run{k}")
        assert result.trials_completed == 8 and result.trials_not_completed == 0
        assert result.sessions_completed == 2
        frame = analyze(load_plan("bio_inspired_palpation"), workspace=tmp_path / f"run{k}").data.frame
        tables.append(frame.drop(columns=["trial"]).reset_index(drop=True))
    pd.testing.assert_frame_equal(tables[0], tables[1])
    assert sorted(tables[0]["participant"].unique()) == ["BIP-V001", "BIP-V002"]
    assert set(tables[0]["group"]) == {"novice", "expert"}  # one per stratum, by the strata's target sizes


def test_workspace_folder_must_be_new(tmp_path):
    from studyctl.errors import UsageError

    (tmp_path / "ws").mkdir()
    (tmp_path / "ws" / "studyctl.toml").write_text("")
    with pytest.raises(UsageError, match="already holds a study"):
        simulate_study("bio_inspired_palpation", 1, 1, tmp_path / "ws")
