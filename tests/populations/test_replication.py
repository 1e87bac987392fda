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
