"""The paired (complete-block) matrix without pivot_table equals pivot_table's, missing cells and all."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from studyctl.analysis.shape import paired_matrix, paired_pivot


def _units(rng: np.random.Generator, people: int, levels: list[str], holes: float, nan: float) -> pd.DataFrame:
    rows = []
    for p in rng.permutation(people):
        for lv in levels:
            if rng.random() < holes:
                continue
            rows.append((f"P{p:03d}", lv, np.nan if rng.random() < nan else float(rng.normal())))
    return pd.DataFrame(rows, columns=["participant", "condition", "value"])


@pytest.mark.parametrize("seed", range(12))
def test_matrix_equals_pivot_table(seed):
    rng = np.random.default_rng(seed)
    levels = ["none", "piecewise", "linear", "bio"]
    sub = _units(rng, int(rng.integers(2, 30)), levels, holes=[0, 0.1, 0.4][seed % 3], nan=[0, 0.05, 0.3][seed % 3])
    for asked in (levels, levels[1:3], ["bio", "none"], ["none", "absent"]):
        m, dropped = paired_matrix(sub, "condition", asked)
        ref, ref_dropped = paired_pivot(sub, "condition", asked)
        assert m.shape == ref.shape and np.array_equal(m, ref) and dropped == ref_dropped


def test_repeated_units_and_numbers_take_pivot_tables_means():
    sub = pd.DataFrame({"participant": ["a", "a", "b", "b", "a"], "condition": ["x", "y", "x", "y", "x"],
                        "value": [1.0, 2.0, 3.0, 4.0, 2.0]})
    m, dropped = paired_matrix(sub, "condition", ["x", "y"])
    assert m.tolist() == [[1.5, 2.0], [3.0, 4.0]] and dropped == []
    nums = pd.DataFrame({"participant": [9, 10, 9, 10], "condition": ["x", "x", "y", "y"], "value": [1., 2., 3., 4.]})
    m, _ = paired_matrix(nums, "condition", ["x", "y"])
    assert m.tolist() == [[1.0, 3.0], [2.0, 4.0]]  # 9 before 10, as pivot_table sorts numbers
