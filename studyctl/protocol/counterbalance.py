"""Counterbalancing schemes as pure functions on condition indices, and balance diagnostics.

Each scheme returns an integer array of shape (sequences, n): row ``s`` is the order of conditions
``0..n-1`` given to every participant allocated to sequence ``s``.

* :func:`williams` — Williams (1949) balanced Latin square: for even n one n×n square in which every
  condition is once in every position and every ordered pair of conditions is adjacent exactly once;
  for odd n the square and its mirror (rows reversed), 2n sequences, every ordered pair adjacent twice.
* :func:`cyclic_latin` — the cyclic Latin square ``(i + r) mod n`` (position-balanced only).
* :func:`all_permutations` — every order, in lexicographic order.
* :func:`random_order` — one seeded random permutation (per participant).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from studyctl.errors import UsageError

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built: loading or checking a
    import pandas as pd  # protocol stays a small process (issue 19: hostile files within 200 MB)


def _check_n(n: int) -> None:
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise UsageError(f"number of conditions must be a positive integer, got {n!r}")


def williams_first_row(n: int) -> np.ndarray:
    """The first row 0, 1, n-1, 2, n-2, … of the Williams construction."""
    _check_n(n)
    row = [0]
    low, high = 1, n - 1
    for i in range(1, n):
        if i % 2:
            row.append(low)
            low += 1
        else:
            row.append(high)
            high -= 1
    return np.asarray(row, dtype=np.int64)


def williams(n: int) -> np.ndarray:
    """Williams balanced Latin square(s) for ``n`` conditions: n rows (even n) or 2n rows (odd n)."""
    first = williams_first_row(n)
    square = (first[None, :] + np.arange(n)[:, None]) % n
    if n % 2 == 1 and n > 1:
        square = np.vstack([square, square[:, ::-1]])
    return square


def cyclic_latin(n: int) -> np.ndarray:
    """The cyclic Latin square: row r is ``(r, r+1, …) mod n``; each condition once per position."""
    _check_n(n)
    return (np.arange(n)[None, :] + np.arange(n)[:, None]) % n


def all_permutations(n: int) -> np.ndarray:
    """Every order of ``n`` conditions (n! rows), lexicographic."""
    _check_n(n)
    if n > 10:
        raise UsageError(f"all permutations of {n} conditions is {math.factorial(n)} orders; use williams or random")
    return np.asarray(list(itertools.permutations(range(n))), dtype=np.int64).reshape(-1, n)


def random_order(n: int, rng: np.random.Generator) -> np.ndarray:
    """One random order of ``n`` conditions drawn from ``rng`` (argsort of n uniforms: stable across numpy)."""
    _check_n(n)
    return np.argsort(rng.random(n), kind="stable")


def position_counts(sequences: np.ndarray, n: int) -> np.ndarray:
    """``counts[c, p]``: how many sequences put condition ``c`` at position ``p`` (0-based)."""
    seqs = np.asarray(sequences, dtype=np.int64).reshape(-1, n) if np.size(sequences) else np.zeros((0, n), int)
    counts = np.zeros((n, n), dtype=np.int64)
    for pos in range(seqs.shape[1]):
        counts[:, pos] = np.bincount(seqs[:, pos], minlength=n)[:n]
    return counts


def carryover_counts(sequences: np.ndarray, n: int) -> np.ndarray:
    """``counts[a, b]``: how often condition ``b`` immediately follows condition ``a``."""
    seqs = np.asarray(sequences, dtype=np.int64)
    counts = np.zeros((n, n), dtype=np.int64)
    if seqs.size == 0 or seqs.shape[-1] < 2:
        return counts
    np.add.at(counts, (seqs[:, :-1].ravel(), seqs[:, 1:].ravel()), 1)
    return counts


@dataclass(frozen=True)
class BalanceReport:
    """Position and carry-over counts of the condition orders given to a group of participants.

    ``position_counts[s, c, p]`` counts participants of stratum ``s`` who had condition ``c`` at
    position ``p`` (0-based); ``carryover_counts[s, a, b]`` counts how often ``b`` directly followed
    ``a``. ``position_spread`` / ``carryover_spread`` are max − min over the counterbalanced conditions
    (0 means perfectly balanced); fixed-first conditions and positions are left out of the spreads.
    """

    strata: tuple[str, ...]
    conditions: tuple[str, ...]
    participants: tuple[int, ...]
    position_counts: np.ndarray
    carryover_counts: np.ndarray
    position_spread: tuple[int, ...]
    carryover_spread: tuple[int, ...]

    def to_frame(self) -> pd.DataFrame:
        """Long table: stratum, kind ('position' | 'carryover'), condition, other, count.

        For ``position`` rows ``other`` is the 1-based position; for ``carryover`` rows it is the
        condition that followed.
        """
        import pandas as pd

        rows = []
        for s, stratum in enumerate(self.strata):
            for c, cond in enumerate(self.conditions):
                for p in range(self.position_counts.shape[2]):
                    rows.append((stratum, "position", cond, str(p + 1), int(self.position_counts[s, c, p])))
            for a, first in enumerate(self.conditions):
                for b, second in enumerate(self.conditions):
                    if a != b:
                        rows.append((stratum, "carryover", first, second, int(self.carryover_counts[s, a, b])))
        return pd.DataFrame(rows, columns=["stratum", "kind", "condition", "other", "count"])

    def summary_frame(self) -> pd.DataFrame:
        """One row per stratum: participants, position_spread, carryover_spread."""
        import pandas as pd

        return pd.DataFrame(
            {
                "stratum": list(self.strata),
                "participants": list(self.participants),
                "position_spread": list(self.position_spread),
                "carryover_spread": list(self.carryover_spread),
            },
            columns=["stratum", "participants", "position_spread", "carryover_spread"],
        )


def balance_report(
    orders: Sequence[tuple[str, Sequence[str]]],
    conditions: Sequence[str],
    strata: Sequence[str],
    fixed_first: Sequence[str] = (),
) -> BalanceReport:
    """Balance diagnostics of ``(stratum, condition order)`` pairs, one per participant.

    Parameters
    ----------
    orders
        For each participant its stratum id and its condition order (one block).
    conditions
        Every condition id (defines the row/column order of the counts).
    strata
        Every stratum id.
    fixed_first
        Conditions that always come first: excluded from the spreads.
    """
    index = {c: i for i, c in enumerate(conditions)}
    n = len(conditions)
    strata = tuple(strata)
    by_stratum: dict[str, list[list[int]]] = {s: [] for s in strata}
    for stratum, order in orders:
        if stratum not in by_stratum:
            raise UsageError(f"unknown stratum {stratum!r}; known: {', '.join(strata)}")
        by_stratum[stratum].append([index[c] for c in order])
    width = max((len(o) for _, o in orders), default=n)
    pos = np.zeros((len(strata), n, width), dtype=np.int64)
    carry = np.zeros((len(strata), n, n), dtype=np.int64)
    cb = [index[c] for c in conditions if c not in fixed_first]
    first_pos = len(fixed_first)
    pos_spread, carry_spread = [], []
    for s, stratum in enumerate(strata):
        seqs = np.asarray(by_stratum[stratum], dtype=np.int64).reshape(-1, width)
        for p in range(width):
            pos[s, :, p] = np.bincount(seqs[:, p], minlength=n)[:n] if len(seqs) else 0
        carry[s] = carryover_counts(seqs, n)
        sub = pos[s][np.ix_(cb, list(range(first_pos, first_pos + len(cb))))] if cb else np.zeros((1, 1))
        pos_spread.append(int(sub.max() - sub.min()) if sub.size else 0)
        pairs = carry[s][np.ix_(cb, cb)]
        off = pairs[~np.eye(len(cb), dtype=bool)] if len(cb) > 1 else np.zeros(1)
        carry_spread.append(int(off.max() - off.min()) if off.size else 0)
    return BalanceReport(
        strata=strata,
        conditions=tuple(conditions),
        participants=tuple(len(by_stratum[s]) for s in strata),
        position_counts=pos,
        carryover_counts=carry,
        position_spread=tuple(pos_spread),
        carryover_spread=tuple(carry_spread),
    )
