"""An analysis result builds its tests table once: a report asks for it about sixty times, and each build deep-copies
every row (``asdict``). Each call still returns a frame of its own."""

from __future__ import annotations

import dataclasses

import pandas as pd

from studyctl.analysis import results as results_mod
from studyctl.analysis.plan import load_plan
from studyctl.analysis.results import AnalysisResult, TestRow


def _row(test_id: str, p: float) -> TestRow:
    fields = {f.name: None for f in dataclasses.fields(TestRow)}
    defaults = {f.name: f.default for f in dataclasses.fields(TestRow) if f.default is not dataclasses.MISSING}
    return TestRow(**{**fields, **defaults, "test_id": test_id, "metric": "m", "test": "rank_sum", "p": p})


def test_to_frame_builds_once_and_returns_copies(monkeypatch) -> None:  # noqa: ANN001
    calls = []
    real = results_mod.rows_frame
    monkeypatch.setattr(results_mod, "rows_frame", lambda rows: calls.append(1) or real(rows))
    result = AnalysisResult(plan=load_plan("bio_inspired_palpation"), data=None, rows=(_row("a", 0.01), _row("b", 0.5)))
    first = result.to_frame()
    first.loc[0, "p"] = 99.0  # a caller changing its frame does not change the next caller's
    second = result.to_frame()
    assert len(calls) == 1
    assert second["p"].tolist() == [0.01, 0.5]
    pd.testing.assert_frame_equal(second, real(result.rows))
    # a replaced result (other rows) builds its own table
    other = dataclasses.replace(result, rows=(_row("c", 0.2),))
    assert other.to_frame()["test_id"].tolist() == ["c"]
    assert len(calls) == 2
