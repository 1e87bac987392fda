"""Counterbalancing schemes: Latin property and Williams carry-over balance (property tests)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from studyctl.errors import UsageError
from studyctl.protocol.counterbalance import (
    all_permutations,
    balance_report,
    carryover_counts,
    cyclic_latin,
    position_counts,
    random_order,
    williams,
    williams_first_row,
)

sizes = st.integers(min_value=1, max_value=16)


def _is_permutation_rows(rows: np.ndarray, n: int) -> bool:
    return all(sorted(row) == list(range(n)) for row in rows.tolist())


@given(sizes)
def test_williams_is_latin_with_equal_positions(n):
    rows = williams(n)
    assert rows.shape == ((2 * n) if n % 2 and n > 1 else n, n)
    assert _is_permutation_rows(rows, n)
    counts = position_counts(rows, n)
    # each condition once per position in every complete set (twice for odd n: square + mirror)
    assert np.all(counts == rows.shape[0] // n)


@given(sizes)
def test_williams_each_ordered_pair_adjacent_equally_often(n):
    rows = williams(n)
    carry = carryover_counts(rows, n)
    off_diagonal = carry[~np.eye(n, dtype=bool)]
    expected = 1 if n % 2 == 0 else 2
    if n > 1:
        assert np.all(off_diagonal == expected)
    assert np.all(np.diag(carry) == 0)


@given(sizes)
def test_even_williams_square_alone_is_carryover_balanced(n):
    if n % 2 == 1:
        n += 1
    square = williams(n)
    assert square.shape == (n, n)
    assert np.all(carryover_counts(square, n)[~np.eye(n, dtype=bool)] == 1)


@pytest.mark.parametrize("n", [3, 5, 7])
def test_odd_williams_single_square_cannot_balance_carryover(n):
    # the reason odd n needs the mirror: the first n rows alone leave some ordered pairs unbalanced
    first_square = williams(n)[:n]
    off = carryover_counts(first_square, n)[~np.eye(n, dtype=bool)]
    assert off.max() != off.min()


def test_williams_first_row_matches_the_classic_construction():
    assert williams_first_row(4).tolist() == [0, 1, 3, 2]
    assert williams_first_row(6).tolist() == [0, 1, 5, 2, 4, 3]
    assert williams(4).tolist() == [[0, 1, 3, 2], [1, 2, 0, 3], [2, 3, 1, 0], [3, 0, 2, 1]]
    assert williams(3).tolist() == [[0, 1, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0], [0, 2, 1], [1, 0, 2]]


@given(sizes)
def test_cyclic_latin_each_condition_once_per_position(n):
    rows = cyclic_latin(n)
    assert rows.shape == (n, n)
    assert np.all(position_counts(rows, n) == 1)
    assert _is_permutation_rows(rows, n)


@given(st.integers(min_value=1, max_value=6))
def test_all_permutations_complete_and_position_balanced(n):
    rows = all_permutations(n)
    assert rows.shape == (math.factorial(n), n)
    assert len({tuple(r) for r in rows.tolist()}) == math.factorial(n)
    assert np.all(position_counts(rows, n) == math.factorial(n - 1))
    if n > 1:
        carry = carryover_counts(rows, n)[~np.eye(n, dtype=bool)]
        assert np.all(carry == carry[0])


@given(st.integers(min_value=1, max_value=20), st.integers(min_value=0, max_value=2**32))
@settings(max_examples=50)
def test_random_order_is_a_seeded_permutation(n, seed):
    a = random_order(n, np.random.default_rng(seed))
    b = random_order(n, np.random.default_rng(seed))
    assert sorted(a.tolist()) == list(range(n))
    assert a.tolist() == b.tolist()


def test_bad_sizes_raise():
    for fn in (williams, cyclic_latin, all_permutations):
        with pytest.raises(UsageError):
            fn(0)
    with pytest.raises(UsageError, match="all permutations of 11"):
        all_permutations(11)


def test_balance_report_counts_and_spreads():
    conditions = ["A", "B", "C", "D"]
    orders = [("s", [conditions[i] for i in row]) for row in williams(4).tolist()]
    report = balance_report(orders, conditions, ["s"])
    assert report.participants == (4,)
    assert report.position_spread == (0,) and report.carryover_spread == (0,)
    frame = report.to_frame()
    assert list(frame.columns) == ["stratum", "kind", "condition", "other", "count"]
    assert len(frame) == 16 + 12
    assert set(frame["count"]) == {1}
    # one participant more breaks the balance by exactly one
    worse = balance_report([*orders, ("s", ["A", "B", "C", "D"])], conditions, ["s"])
    assert worse.position_spread == (1,) and worse.carryover_spread == (1,)
    assert worse.summary_frame().to_dict("records") == [
        {"stratum": "s", "participants": 5, "position_spread": 1, "carryover_spread": 1}
    ]


def test_balance_report_ignores_fixed_first_condition():
    rest = ["RT", "ES", "EG", "ESG"]
    orders = [("all", ["BL", *[rest[i] for i in row]]) for row in williams(4).tolist()]
    report = balance_report(orders, ["BL", *rest], ["all"], fixed_first=["BL"])
    assert report.position_spread == (0,) and report.carryover_spread == (0,)
    assert report.position_counts[0, 0].tolist() == [4, 0, 0, 0, 0]


def test_all_orderings_of_small_williams_inputs_agree_with_brute_force():
    # brute force: count adjacent pairs directly from the rows
    for n in range(2, 8):
        rows = williams(n).tolist()
        pairs = {}
        for row in rows:
            for a, b in itertools.pairwise(row):
                pairs[(a, b)] = pairs.get((a, b), 0) + 1
        assert set(pairs) == {(a, b) for a in range(n) for b in range(n) if a != b}
        assert len(set(pairs.values())) == 1
