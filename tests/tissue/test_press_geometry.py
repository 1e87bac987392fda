"""The tissue palpator's press geometry (tissue_decision._points, squared_distances) builds the arrays its evidence
is weighed on more cheaply than the nested-list array and the (n, m, 2) square-and-sum it replaced: the two must agree
to the bit, signed zeros, NaN and infinite coordinates included."""

import math

import numpy as np

from studyctl.participants.tissue_decision import _points, squared_distances


def test_points_equal_an_array_of_pairs():
    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 17, 200):
        rows = [{"x": float(x), "y": float(y), "stage": "survey"} for x, y in rng.uniform(-5, 65, (n, 2))]
        want = np.array([[r["x"], r["y"]] for r in rows])
        got = _points(rows)
        assert got.shape == want.shape and got.dtype == want.dtype and got.tobytes() == want.tobytes()
    assert _points([]).shape == (0, 2)


def test_squared_distances_equal_the_square_and_sum():
    rng = np.random.default_rng(4)
    for _ in range(200):
        n, m = int(rng.integers(1, 120)), int(rng.integers(1, 120))
        a = rng.uniform(-10, 70, (n, 2)) * 10.0 ** rng.integers(-3, 3)
        b = a[rng.random(n) < 0.7] if rng.random() < 0.5 else rng.uniform(-10, 70, (m, 2))
        if rng.random() < 0.2:
            a[rng.random((n, 2)) < 0.1] = rng.choice([0.0, -0.0, math.nan, math.inf, -math.inf])
        want = ((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=2)
        with np.errstate(invalid="ignore"):
            got = squared_distances(a, b)
        assert got.shape == want.shape and got.tobytes() == want.tobytes()
