"""``np.mean`` of a short list of floats, and ``np.median`` of a float array, bit for bit, with less overhead.

A virtual palpator scores each cell from the mean of its few presses' log-percepts, tens of times per press, and
``float(np.mean(list))`` spends ~12 µs converting the list and entering the ufunc machinery for a sum of 1-12
numbers (0.4-1 µs here). A plain ``sum(v) / len(v)`` would round differently from eight presses on: numpy adds
``float64`` numbers by pairwise summation (``pairwise_sum`` in numpy's ``loops_utils.h.src``: sequential below 8
numbers, eight running sums up to 128, halves above), starting its reduction from the identity 0.0. This module
does the same additions in the same order, so seeded sessions stay identical (tests compare it with ``np.mean``
over sizes 1-9000 and signed zeros).

The seed-003 palpator takes medians of its presses' cues (a few hundred values) several times per press:
``np.median`` / ``np.nanmedian`` of 150 values take 17 / 24 µs, mostly Python around a 3 µs partition.
:func:`numpy_median` sorts instead (4 / 5 µs) and averages the middle values the way ``np.median`` does (it calls
``np.mean`` on them).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

_BLOCK = 128  # numpy's PW_BLOCKSIZE


def _pairwise(a: Sequence[float], lo: int, n: int) -> float:
    if n < 8:
        return sum(a[lo:lo + n], -0.0)  # numpy starts its short sums at -0.0 (keeps a sum of -0.0s negative)
    if n <= _BLOCK:
        r0, r1, r2, r3, r4, r5, r6, r7 = a[lo:lo + 8]
        end = lo + n - n % 8
        for i in range(lo + 8, end, 8):
            r0 += a[i]
            r1 += a[i + 1]
            r2 += a[i + 2]
            r3 += a[i + 3]
            r4 += a[i + 4]
            r5 += a[i + 5]
            r6 += a[i + 6]
            r7 += a[i + 7]
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        for i in range(end, lo + n):
            res += a[i]
        return res
    half = n // 2
    half -= half % 8
    return _pairwise(a, lo, half) + _pairwise(a, lo + half, n - half)


def numpy_mean(values: Sequence[float]) -> float:
    """``float(np.mean(values))`` for a non-empty sequence of floats (Python or numpy ``float64``), same bits."""
    n = len(values)
    return float((0.0 + _pairwise(values, 0, n)) / n)  # 0.0: the add reduction's identity, where numpy starts


def median_of_sorted(ordered: np.ndarray) -> float:
    """``float(np.median(values))`` where ``ordered`` is ``np.sort(values)`` (1-D float64, not empty), same bits.

    ``np.median`` partitions the values so the middle one (odd count) or two (even) are in place, takes their
    ``np.mean`` and returns NaN if any value is NaN. Sorting puts the same values there (equal floats are the same
    bits, but for zeros, whose sign the mean's ``0.0 +`` start drops) and NaN last."""
    n = ordered.size
    if math.isnan(ordered[-1]):
        return math.nan
    mid = n // 2
    return numpy_mean([float(ordered[mid])] if n % 2 else [float(ordered[mid - 1]), float(ordered[mid])])


def numpy_median(values: np.ndarray) -> float:
    """``float(np.median(values))`` of a non-empty 1-D float64 array, same bits (:func:`median_of_sorted`)."""
    return median_of_sorted(np.sort(values))


def numpy_nanmedian(values: np.ndarray) -> float:
    """``float(np.nanmedian(values))`` of a 1-D float64 array, same bits: the median of its values that are not NaN
    (numpy's 1-D path does just that), NaN when there are none (numpy also warns)."""
    present = values[~np.isnan(values)]
    return numpy_median(present) if present.size else math.nan
