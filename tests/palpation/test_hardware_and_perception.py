"""Sensor/ADC calibration, balloon and motor models, eqs. 3-6, and the Weber observer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.errors import ModelParameterError
from studyctl.models.palpation_hw import A201, K_PSI_N_PER_MM2, BalloonModel, VibrationMotorModel
from studyctl.models.perception import (
    Sense,
    balloon_control_for_force,
    balloon_force_for_control,
    inverse_perception,
    perceived_force_intensity,
    perceived_vibration_intensity,
)


@pytest.mark.parametrize(
    ("counts", "force"),
    # research/capr.md §4: the BHF polynomial at a = 0, 100, 156, 255 (a = counts / 4)
    [(0, -0.0381), (400, 1.05), (624, 2.0), (1020, 4.51)],
)
def test_calibration_curve_values(counts, force):
    assert A201.force(counts) == pytest.approx(force, abs=0.01)
    assert A201.force_of_count(counts) == pytest.approx(A201.force(counts), abs=1e-15)


def test_piecewise_thresholds_are_calibrated_adc_values():
    """The BHF code's thresholds: the calibrated forces of 200, 250, 300, 700 counts (÷4 = 8-bit units)."""
    got = [A201.force(c) for c in (200, 250, 300, 700)]
    assert got == pytest.approx([0.4307, 0.5696, 0.7189, 2.3846], abs=5e-5)


def test_inverse_calibration_round_trips_and_saturates():
    counts = np.arange(0, 1024)
    assert np.array_equal(A201.counts(A201.force(counts)), counts)
    assert all(A201.count_of_force(A201.force_of_count(c)) == c for c in range(0, 1024, 7))
    assert A201.counts(-5.0) == 0 and A201.counts(50.0) == 1023
    assert A201.count_of_force(-5.0) == 0 and A201.count_of_force(50.0) == 1023
    lo, hi = A201.force_range_n
    assert lo == pytest.approx(-0.0381) and hi == pytest.approx(4.538, abs=1e-3)


@pytest.mark.parametrize("bad", [-1, 1024, 5000, float("nan")])
def test_adc_values_outside_the_range_are_rejected(bad):
    with pytest.raises(ModelParameterError, match=r"ADC value .* is outside the 10-bit range 0\.\.1023"):
        A201.force(bad)
    with pytest.raises(ModelParameterError):
        A201.force(np.array([10, bad]))


def test_pressure_over_the_sensing_area():
    assert A201.pressure_kpa(1.0) == pytest.approx(1.0 / (math.pi * 0.004765**2) / 1e3)


def test_balloon_curve_and_dynamics():
    m = BalloonModel()
    assert m.static_psi(36) == 0.0 and m.static_psi(20) == 0.0
    assert m.static_psi(96) == pytest.approx(15.0)  # BHF fit 0.25·C − 9
    assert m.static_psi(100) == pytest.approx(16.0)
    assert BalloonModel(slope_psi=1.0).static_psi(100) == 20.0  # the regulator caps at 20 psi
    assert m.static_psi(float("nan")) == 0.0
    psi = 0.0
    for _ in range(5):  # one time constant in 5 steps
        psi = m.step(psi, 96, m.tau_s / 5)
    assert psi == pytest.approx(15.0 * (1 - math.exp(-1)))


def test_motor_rises_with_duty_and_stalls_below_start():
    m = VibrationMotorModel()
    duties = np.linspace(0, 100, 101)
    f, a = np.array([m.static(d) for d in duties]).T
    assert np.all(f[duties <= 24] == 0) and np.all(a[duties <= 24] == 0)
    assert np.all(np.diff(f[duties >= 24]) > 0) and np.all(np.diff(a[duties >= 24]) > 0)
    assert m.static(100) == (pytest.approx(250.0), pytest.approx(12.0))
    assert m.output(m.step(0.0, 100.0, 10.0)) == m.static(100)


def test_eq3_eq4_eq6():
    assert perceived_force_intensity(60.0, 1.0) == pytest.approx(6.0)
    assert perceived_vibration_intensity(10, 20, 30, 2.0) == pytest.approx(2 * (2.9 + 7.2 + 13.8) / 10)
    assert inverse_perception(0.0, 36, 0.1) == 36.0
    assert inverse_perception(2.0, 36, 0.1) == pytest.approx(36 * 1.21)
    assert inverse_perception(100.0, 36, 0.1) == 99.0
    with pytest.raises(ModelParameterError, match="C0 = 0"):
        inverse_perception(1.0, 0, 0.1)


def test_eq5_balloon_control_for_force():
    """Eq. 5 with K_psi = 6.896e-3, r_p = 2 mm, C_p0 = 36: 1 N → 5/(6.896e-3·π·4) + 36."""
    assert K_PSI_N_PER_MM2 == pytest.approx(0.454 * 9.8 / 25.4**2, rel=1e-3)
    assert balloon_control_for_force(0.0) == 36.0
    assert balloon_control_for_force(0.1) == pytest.approx(0.5 / (6.896e-3 * math.pi * 4) + 36)
    assert balloon_force_for_control(balloon_control_for_force(0.07)) == pytest.approx(0.07)
    with pytest.raises(ModelParameterError):
        balloon_control_for_force(1.0, r_p_mm=0)


def test_weber_observer_discriminates_one_fraction_75_percent_of_the_time():
    from scipy import stats
    rng = np.random.default_rng(7)
    sense = Sense("pressure", threshold=0.0, weber=0.1)
    n = 40000
    a = np.array([sense.observe(10.0, rng) for _ in range(n)])
    b = np.array([sense.observe(11.0, rng) for _ in range(n)])
    p = np.mean(b > a)
    assert p == pytest.approx(0.75, abs=0.01)
    assert stats.shapiro(np.log(a[:2000])).pvalue > 0.001  # log-normal noise
    assert sense.observe(0.0, rng) == 0.0 and sense.observe(float("nan"), rng) == 0.0
    faint = Sense("vibration", threshold=1.0, weber=0.2)
    assert np.mean([faint.observe(0.5, rng) > 0 for _ in range(2000)]) < 0.01
    with pytest.raises(ModelParameterError, match="Weber fraction 0"):
        Sense("x", 0.1, 0.0)
