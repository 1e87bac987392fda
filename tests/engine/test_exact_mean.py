"""``numpy_mean``: the seed-000 palpator's cell means without numpy arrays, the same bits as ``np.mean``;
``numpy_median`` and ``numpy_nanmedian``: the seed-003 palpator's cue medians, the same bits as ``np.median`` and
``np.nanmedian``."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from studyctl.participants.exact_mean import numpy_mean, numpy_median, numpy_nanmedian

SIZES = [*range(1, 140), 200, 255, 256, 257, 1000, 8193, 9000]


@pytest.mark.parametrize("n", SIZES)
def test_same_bits_as_numpy_mean(n):
    rng = np.random.default_rng(n)
    for _ in range(40 if n < 140 else 3):
        # magnitudes over 7 decades, so a different order of additions shows in the last bits
        v = (rng.standard_normal(n) * 10.0 ** rng.integers(-3, 4, n)).tolist()
        assert numpy_mean(v) == float(np.mean(v))  # == on floats: the same number, to the bit
        assert numpy_mean(np.asarray(v)) == float(np.mean(v))  # numpy float64 elements as well


def test_a_plain_sum_would_differ_from_eight_numbers_on():
    # what makes the pairwise order necessary (why not sum(v) / len(v))
    rng = np.random.default_rng(0)
    lists = [(rng.standard_normal(8) * 10.0 ** rng.integers(-3, 4, 8)).tolist() for _ in range(200)]
    assert any(sum(v) / len(v) != float(np.mean(v)) for v in lists)


@pytest.mark.parametrize("v", [[-0.0], [-0.0] * 9, [0.0, -0.0], [math.inf, 1.0], [math.inf, -math.inf], [math.nan, 2.0],
                               [1e308, 1e308]])
def test_signed_zeros_and_non_finite_values_as_numpy(v):
    with np.errstate(all="ignore"):
        want = float(np.mean(v))
    got = numpy_mean(v)
    assert (math.isnan(got) and math.isnan(want)) or (got == want and math.copysign(1, got) == math.copysign(1, want))


def test_the_palpator_scores_without_numpy_means(monkeypatch):
    """The decision code calls numpy_mean, not np.mean (fails on the old code, which called np.mean)."""
    import studyctl.participants.palpator_decision as decision

    assert decision.numpy_mean is numpy_mean


def _same(got: float, want: float) -> bool:
    return (math.isnan(got) and math.isnan(want)) or (got == want and math.copysign(1, got) == math.copysign(1, want))


@pytest.mark.parametrize("n", [*range(1, 40), 199, 200, 1000, 4097])
def test_numpy_median_same_bits_as_numpy(n):
    rng = np.random.default_rng(n)
    for k in range(20):
        v = rng.standard_normal(n) * 10.0 ** rng.integers(-3, 4, n)
        if k % 4 == 1:
            v = np.round(v, 1)  # ties
        if k % 4 == 2:
            v[rng.random(n) < 0.3] = rng.choice([0.0, -0.0, math.inf, -math.inf])
        assert _same(numpy_median(v), float(np.median(v)))
        if k % 4 == 3:
            v[rng.random(n) < 0.3] = math.nan
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            assert _same(numpy_nanmedian(v), float(np.nanmedian(v)))
            assert _same(numpy_median(v), float(np.median(v)))


@pytest.mark.parametrize("v", [[-0.0], [-0.0, -0.0], [0.0, -0.0, -0.0], [math.nan], [math.nan, math.nan],
                               [1.0, math.nan], [math.inf, -math.inf], [math.inf, math.inf, 1.0]])
def test_numpy_median_edge_values_as_numpy(v):
    a = np.array(v)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert _same(numpy_median(a), float(np.median(a)))
        assert _same(numpy_nanmedian(a), float(np.nanmedian(a)))
