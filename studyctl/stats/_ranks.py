"""Mid-ranks and tie bookkeeping, computed once from one stable sort."""

from __future__ import annotations

import numpy as np


def midranks(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mid-ranks of ``values`` with their tie structure.

    Returns ``(doubled_ranks, group_doubled_rank, group_size)``: ``doubled_ranks`` are the integer
    doubled mid-ranks (2 × rank, so 1.5 becomes 3) in the input order; the other two arrays describe
    each run of equal values in increasing order. Doubling keeps every rank an exact integer, which
    the exact tie-aware distributions need.
    """
    n = values.size
    order = np.argsort(values, kind="stable")
    sorted_vals = values[order]
    if n == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty
    starts = np.flatnonzero(np.concatenate(([True], sorted_vals[1:] != sorted_vals[:-1])))
    ends = np.concatenate((starts[1:], [n]))  # exclusive
    sizes = ends - starts
    # 1-based positions start+1 … end; doubled mean rank = (start+1) + end
    group_r2 = (starts + 1 + ends).astype(np.int64)
    r2 = np.empty(n, dtype=np.int64)
    r2[order] = np.repeat(group_r2, sizes)
    return r2, group_r2, sizes.astype(np.int64)


def tie_term(sizes: np.ndarray) -> float:
    """Σ(t³ − t) over tie groups, exact (Python integers) and returned as float."""
    tied = sizes[sizes > 1]
    return float(sum(int(t) ** 3 - int(t) for t in tied.tolist()))
