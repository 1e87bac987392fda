"""How often a same-size replication gives a published verdict, against closed forms computed with mpmath."""

from __future__ import annotations

import mpmath
import pytest

from studyctl.calibration.replication import verdict_replication
from studyctl.errors import StatsInputError


def _phi(x):
    return 0.5 * mpmath.erfc(-x / mpmath.sqrt(2))


def _reference(p, alpha, significant, directed=False):
    """Φ((z − z_α)/√2) (+ Φ((−z − z_α)/√2) unless directed) with z = Φ⁻¹(1 − p/2), in 40-digit arithmetic."""
    mpmath.mp.dps = 40
    z = -mpmath.sqrt(2) * mpmath.erfinv(mpmath.mpf(p) - 1)  # Φ⁻¹(1 − p/2)
    za = -mpmath.sqrt(2) * mpmath.erfinv(mpmath.mpf(alpha) - 1)
    same, other = _phi((z - za) / mpmath.sqrt(2)), _phi((-z - za) / mpmath.sqrt(2))
    sig = same if directed else same + other
    return float(sig if significant else 1 - same - other)


@pytest.mark.parametrize(("p", "significant"), [(0.071, False), (0.034, True), (1.73e-7, True), (0.684, False),
                                                (0.048, True), (1.0, False), (1e-12, True)])
def test_matches_the_closed_form(p, significant):
    assert verdict_replication(p, 0.05, significant=significant) == pytest.approx(
        _reference(p, 0.05, significant), abs=1e-12)
    if significant:
        assert verdict_replication(p, 0.05, significant=True, directed=True) == pytest.approx(
            _reference(p, 0.05, True, directed=True), abs=1e-12)


def test_a_p_at_the_level_replicates_half_the_time_and_strong_evidence_nearly_always():
    assert verdict_replication(0.05, 0.05, significant=True, directed=True) == pytest.approx(0.5, abs=1e-12)
    assert verdict_replication(1e-12, 0.05, significant=True) > 0.999
    # no effect seen (p = 1, z = 0): a replication is significant either way with 2·Φ(−z_α/√2) = 0.166
    assert verdict_replication(1.0, 0.05, significant=False) == pytest.approx(
        1 - 2 * float(_phi(-mpmath.mpf("1.959963984540054") / mpmath.sqrt(2))), abs=1e-9)
    # monotone: the smaller a significant p, the likelier a replication is significant too
    ps = [0.049, 0.01, 1e-3, 1e-6]
    assert [verdict_replication(p, 0.05, significant=True) for p in ps] == sorted(
        verdict_replication(p, 0.05, significant=True) for p in ps)


def test_impossible_p_or_alpha_is_an_error():
    for p, alpha in ((0.0, 0.05), (1.5, 0.05), (0.1, 0.0)):
        with pytest.raises(StatsInputError):
            verdict_replication(p, alpha, significant=False)


def test_a_replication_lands_in_a_196_se_band_five_times_in_six():
    """Its estimate ~ N(value, 2·SE²): inside ±1.96 SE with P(|Z| < 1.96/√2), closed form in mpmath."""
    from studyctl.calibration.replication import band_replication

    mpmath.mp.dps = 30
    expected = float(mpmath.erf(mpmath.mpf("1.96") / 2))  # P(|Z| < 1.96/√2) = erf(1.96/2)
    assert band_replication(29.15, 2.54, 29.15 - 1.96 * 2.54, 29.15 + 1.96 * 2.54) == pytest.approx(expected,
                                                                                                    abs=1e-12)
    assert 0.83 < expected < 0.84
    # a one-sided band (a proportion at its top): only the lower edge can be missed
    one = band_replication(1.0, 0.02, 0.95, 1.0)
    assert one == pytest.approx(float(_phi(mpmath.mpf(0)) - _phi(mpmath.mpf(-0.05) / (mpmath.sqrt(2) * 0.02))),
                                abs=1e-12)


def test_a_spread_of_n_people_lies_within_a_factor_of_its_published_value():
    from studyctl.calibration.replication import spread_replication

    mpmath.mp.dps = 30
    # log ratio ~ N(0, 1/(n − 1)): n = 20, factor 1.5 → 2Φ(ln 1.5 · √19) − 1
    expected = float(2 * _phi(mpmath.log(mpmath.mpf("1.5")) * mpmath.sqrt(19)) - 1)
    assert spread_replication(20, 1.5) == pytest.approx(expected, abs=1e-12)
    assert spread_replication(5, 1.5) < spread_replication(20, 1.5) < spread_replication(200, 1.5)
    with pytest.raises(StatsInputError):
        spread_replication(1, 1.5)


def test_a_band_edge_at_the_limit_of_a_proportion_cannot_be_crossed():
    """40/40 nodules found: a Wilson band [0.912, 1] whose top is a proportion's own limit; a replication misses
    it only below 0.912 (not half the time, as a normal estimate around 1.0 would say if the top counted)."""
    from studyctl.calibration import agreement
    from studyctl.calibration.simulated import SimulatedStats, SimulatedValue
    from studyctl.populations.targets import Target

    t = Target("nodules", "sensitivity", "proportion", 1.0, "fit", {"condition": "haptic"},
               {"interval": [0.912, 1.0], "basis": "wilson", "n": 40})
    sim = SimulatedStats((SimulatedValue("nodules", "proportion", 0.95, 0.9, 1.0, 0.02),))
    row = agreement([t], sim, 0.05).rows[0]
    assert 0.99 < row.replication <= 1.0
