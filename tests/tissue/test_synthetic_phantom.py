"""The synthetic phantoms are what the papers describe, and behave like stiff inclusions should."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.errors import ModelParameterError
from studyctl.models.synthetic_phantom import (
    bonded_layer_factor,
    curved_phantom_002,
    hertz_force_n,
    silicone_block_003,
)


def _at(m, k, x, y):
    return m.normal_n[k, int(np.argmin(abs(m.xs_mm - x))), int(np.argmin(abs(m.ys_mm - y)))]


def test_seed003_block_matches_the_paper():
    ph = silicone_block_003(np.random.default_rng(0))
    m = ph.stiffness
    assert m.shape == (6, 159, 59)
    np.testing.assert_array_equal(m.depths_mm, [2, 3, 4, 5, 6, 7])
    assert m.horizontal_n is not None
    assert [(n.name, n.diameter_mm, n.top_depth_mm) for n in ph.nodules] == [("A", 10, 6), ("B", 8, 6), ("C", 6, 6)]
    assert {n.modulus_kpa for n in ph.nodules} == {1590.0}
    assert ph.parameters["tissue_kpa"] == 15.3 and ph.parameters["block_mm"] == (120.0, 120.0, 25.0)
    assert ph.footprint_mm == (0.0, 120.0, 0.0, 120.0)
    assert "approximation" in m.source


def test_seed002_phantom_matches_the_paper():
    ph = curved_phantom_002(np.random.default_rng(0))
    assert ph.stiffness.depths_mm.tolist() == [2.0, 4.0, 6.0]
    assert ph.surface_heights_mm.shape == (31, 26)
    assert [(n.diameter_mm, n.top_depth_mm) for n in ph.nodules] == [(15.0, 3.0), (15.0, 3.0)]
    h = ph.surface_heights_mm
    assert h[15, 13] > h[0, 0] and h[15, 13] > h[-1, -1]  # curved: higher in the middle


def test_homogeneous_tissue_is_hertz_on_a_bonded_layer():
    ph = silicone_block_003(np.random.default_rng(0), nodules=(), noise_n=0.0)
    m = ph.stiffness
    for k, d in enumerate(m.depths_mm):
        expected = (16 / 9) * 15.3e3 * math.sqrt(5e-3) * (d * 1e-3) ** 1.5 * bonded_layer_factor(5.0, d, 25.0)
        np.testing.assert_allclose(m.normal_n[k], expected, rtol=1e-12)
    assert hertz_force_n(15.3, 5.0, 7.0) == pytest.approx(1.1264, abs=1e-4)
    assert bonded_layer_factor(5.0, 1e-12, 25.0) == pytest.approx(1.0)


def test_nodules_stiffen_in_order_of_size_and_more_when_pressed_deeper():
    ph = silicone_block_003(np.random.default_rng(0), noise_n=0.0)
    m = ph.stiffness
    base = [float(np.median(m.normal_n[k])) for k in range(6)]
    contrast = {n.name: [_at(m, k, n.x_mm, n.y_mm) / base[k] - 1 for k in range(6)] for n in ph.nodules}
    for k in range(6):
        assert contrast["A"][k] > contrast["B"][k] > contrast["C"][k] > 0.05
    assert contrast["A"][5] > contrast["A"][0]
    assert np.all(np.diff(m.normal_n, axis=0) > 0)  # force grows with depth everywhere


def test_noise_comes_from_the_passed_generator():
    a = silicone_block_003(np.random.default_rng(5)).stiffness.normal_n
    b = silicone_block_003(np.random.default_rng(5)).stiffness.normal_n
    c = silicone_block_003(np.random.default_rng(6)).stiffness.normal_n
    clean = silicone_block_003(np.random.default_rng(6), noise_n=0.0).stiffness.normal_n
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.std(c - clean) == pytest.approx(0.003, rel=0.05)


def test_bad_generator_input():
    with pytest.raises(ModelParameterError, match="numpy.random.Generator"):
        silicone_block_003(42)  # type: ignore[arg-type]
    with pytest.raises(ModelParameterError, match="noise_n"):
        silicone_block_003(np.random.default_rng(0), noise_n=-1.0)
    with pytest.raises(ModelParameterError, match="tissue_kpa"):
        curved_phantom_002(np.random.default_rng(0), tissue_kpa=0.0)
