"""Friedman's within-row mid-ranks and tie term, computed without a loop over rows, equal scipy's ``rankdata``
and the per-row ``tie_term`` bit for bit (the report's effect-size bootstrap runs Friedman thousands of times)."""

from __future__ import annotations

import numpy as np
from scipy.stats import rankdata

from studyctl.stats import friedman
from studyctl.stats._ranks import tie_term
from studyctl.stats.repeated import _row_midranks


def _reference(y: np.ndarray) -> tuple[np.ndarray, float]:
    ties = 0.0
    for row in y:
        _, counts = np.unique(row, return_counts=True)
        ties += tie_term(counts)
    return rankdata(y, axis=1), ties


def test_row_midranks_equal_rankdata_and_tie_term() -> None:
    rng = np.random.default_rng(22)
    for i in range(600):
        n, k = int(rng.integers(1, 30)), int(rng.integers(2, 8))
        if i % 3 == 0:  # heavy ties, as Likert answers and counts give
            y = rng.integers(0, 4, (n, k)).astype(float)
        elif i % 3 == 1:
            y = rng.normal(size=(n, k))
        else:  # signed zeros tie with zeros, as in np.unique
            y = np.round(rng.normal(size=(n, k)), 1)
            y[rng.random((n, k)) < 0.2] = -0.0
        ranks, ties = _row_midranks(y)
        ref_ranks, ref_ties = _reference(y)
        assert ranks.dtype == ref_ranks.dtype and np.array_equal(ranks, ref_ranks)
        assert ranks.sum(axis=0).tobytes() == ref_ranks.sum(axis=0).tobytes()
        assert isinstance(ties, float) and ties == ref_ties


def test_friedman_with_ties_by_hand() -> None:
    # Mid-ranks by row: [1, 2.5, 2.5], [1.5, 1.5, 3], [3, 1.5, 1.5], [1, 2.5, 2.5], [2, 2, 2]; rank sums 8.5, 10,
    # 11.5 → 12 · 4.5 / (5 · 3 · 4) = 0.9; ties 4 · (2³ − 2) + (3³ − 3) = 48 → C = 1 − 48 / (5 · 24) = 0.6; Q = 1.5.
    y = np.array([[1, 2, 2], [2, 2, 3], [3, 1, 1], [1, 3, 3], [2, 2, 2]], dtype=float)
    res = friedman(*y.T)
    assert res.statistic == 1.5
    assert res.kendall_w == 1.5 / (5 * 2)
