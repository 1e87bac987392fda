"""The studentized-range tables shipped in the wheel, the quantile's vectorised bracketing, and input checks
that must never let a non-number through as a silent result."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from studyctl.errors import StatsInputError
from studyctl.stats import studentized_range as sr
from studyctl.stats import studentized_range_ppf, studentized_range_sf, wilson_interval


@pytest.mark.parametrize("k", [3, 7, 20])
def test_shipped_table_equals_a_fresh_build(k):
    shipped = sr._shipped_coefficients(k)
    assert shipped is not None, "studentized_range_tables.npz is missing from the package"
    fresh = sr.build_range_table(k)
    np.testing.assert_array_equal(shipped[0], fresh.t)
    np.testing.assert_allclose(shipped[1], fresh.c, rtol=1e-13, atol=1e-13)


def test_k_beyond_the_shipped_tables_is_built_on_first_use():
    assert sr._shipped_coefficients(21) is None
    assert studentized_range_sf(4.0, 21, 40) == pytest.approx(studentized_range_sf(4.0, 21, 40.0))


@pytest.mark.parametrize("p", [0.5, 0.9, 0.95, 0.99, 0.999])
@pytest.mark.parametrize("k", [2, 3, 5, 12, 25])
@pytest.mark.parametrize("df", [1.5, 4, 10, 55, math.inf])
def test_quantile_solves_the_survival_function(p, k, df):
    q = studentized_range_ppf(p, k, df)
    assert studentized_range_sf(q, k, df) == pytest.approx(1 - p, rel=1e-11)
    # the root is bracketed: a hair either side is on the right side of 1 − p
    assert studentized_range_sf(q * (1 - 1e-9), k, df) > 1 - p > studentized_range_sf(q * (1 + 1e-9), k, df)


def test_quantile_beyond_the_coarse_grid():
    q = studentized_range_ppf(0.999, 20, 1.5)  # far above the 12.0 end of the first bracket
    assert q > 12
    assert studentized_range_sf(q, 20, 1.5) == pytest.approx(1e-3, rel=1e-10)


def test_non_finite_q():
    with pytest.raises(StatsInputError, match="NaN"):
        studentized_range_sf(float("nan"), 3, 10)
    assert studentized_range_sf(math.inf, 3, 10) == 0.0
    assert studentized_range_sf(-math.inf, 3, 10) == 1.0
    with pytest.raises(StatsInputError):
        studentized_range_sf(3.0, 3, float("nan"))


@pytest.mark.parametrize("bad", ["2", b"2", True, 2.5, -1, float("nan"), None])
def test_counts_must_be_integers(bad):
    with pytest.raises(StatsInputError, match="successes must be a non-negative integer"):
        wilson_interval(bad, 3)


def test_integral_numbers_are_counts():
    assert wilson_interval(np.int64(2), 3.0).successes == 2


@pytest.mark.slow
def test_first_tukey_call_in_a_fresh_process_reads_the_shipped_table():
    code = (
        "import numpy as np\n"
        "from studyctl.stats import studentized_range as sr, tukey_hsd\n"
        "g = [np.arange(12.0) + i for i in range(5)]\n"
        "tukey_hsd(*g)\n"
        "assert sr._range_table.cache_info().currsize == 1\n"
        "import scipy.interpolate as si\n"
        "print(type(sr._range_table(5)).__name__, sr._shipped_coefficients(5) is not None)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["BSpline", "True"]


@pytest.mark.slow  # fresh interpreters: ~23 s in the loaded fast run
def test_quantile_is_bit_identical_across_processes():
    # scipy's BarycentricInterpolator permutes nodes at random: the polish must not depend on process state
    code = "from studyctl.stats import studentized_range_ppf as f; print(repr(f(0.95, 4, 96)), repr(f(0.99, 7, 33)))"
    runs = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
            for _ in range(4)}
    assert len(runs) == 1
