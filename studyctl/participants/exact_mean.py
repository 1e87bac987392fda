"""``np.mean`` of a short list of floats, bit for bit, without building an array.

A virtual palpator scores each cell from the mean of its few presses' log-percepts, tens of times per press, and
``float(np.mean(list))`` spends ~12 µs converting the list and entering the ufunc machinery for a sum of 1-12
numbers (0.4-1 µs here). A plain ``sum(v) / len(v)`` would round differently from eight presses on: numpy adds
``float64`` numbers by pairwise summation (``pairwise_sum`` in numpy's ``loops_utils.h.src``: sequential below 8
numbers, eight running sums up to 128, halves above), starting its reduction from the identity 0.0. This module
does the same additions in the same order, so seeded sessions stay identical (tests compare it with ``np.mean``
over sizes 1-9000 and signed zeros).
"""

from __future__ import annotations

from collections.abc import Sequence

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
