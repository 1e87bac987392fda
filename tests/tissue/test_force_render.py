"""Force rendering: interpolation exactness, explicit clamping at the table's edges and depths, the
retraction rule, the 3.3 N clamp, force directions and the trial's orientation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.errors import ModelParameterError
from studyctl.models.force_lookup import INTERPOLATIONS, make_lookup
from studyctl.models.force_render import ForceRenderer, Placement, RenderParams, reference_forces
from studyctl.models.stiffness_map import StiffnessMap
from studyctl.models.surface_mesh import SurfaceMesh

X0, Y0, DX, DY = 5.0, -4.0, 0.8, 2.0
DEPTHS = [2.0, 3.0, 4.5, 5.0, 7.0]  # deliberately non-uniform


def _linear_field(x, y, d):
    return 0.3 + 0.02 * x - 0.015 * y + 0.11 * d


def _map(field=_linear_field, nx=40, ny=20, horizontal_scale=0.1) -> StiffnessMap:
    xs = X0 + DX * np.arange(nx)
    ys = Y0 + DY * np.arange(ny)
    d, x, y = np.meshgrid(DEPTHS, xs, ys, indexing="ij")
    normal = field(x, y, d)
    return StiffnessMap.from_arrays(
        normal, DEPTHS, dx_mm=DX, dy_mm=DY, horizontal=normal * horizontal_scale, x0_mm=X0, y0_mm=Y0
    )


def _flat_mesh(height=20.0):
    return SurfaceMesh.from_height_grid([-50.0, 100.0], [-50.0, 100.0], np.full((2, 2), height), cell_mm=5.0)


@pytest.mark.parametrize("interpolation", ["linear", "cubic"])
def test_interpolation_is_exact_on_linear_fields(interpolation):
    m = _map()
    look = make_lookup(m, interpolation)
    rng = np.random.default_rng(0)
    x0, x1, y0, y1 = m.extent_mm
    for _ in range(300):
        x, y, d = rng.uniform(x0, x1), rng.uniform(y0, y1), rng.uniform(DEPTHS[0], DEPTHS[-1])
        fn, fh = look(x, y, d)
        assert fn == pytest.approx(_linear_field(x, y, d), rel=1e-12, abs=1e-12)
        assert fh == pytest.approx(0.1 * _linear_field(x, y, d), rel=1e-12, abs=1e-12)
    # the far corner node is reached exactly (cell index clamped to n − 2, fraction 1)
    assert look(x1, y1, DEPTHS[-1])[0] == pytest.approx(_linear_field(x1, y1, DEPTHS[-1]))


def test_linear_is_exact_on_multilinear_and_powerlaw_on_power_laws():
    bilinear = lambda x, y, d: 0.2 + 0.01 * x * y * d + 0.05 * d  # noqa: E731
    look = make_lookup(_map(bilinear), "linear")
    assert look(9.3, 3.1, 4.0)[0] == pytest.approx(bilinear(9.3, 3.1, 4.0))
    hertz = lambda x, y, d: (1.0 + 0.01 * x) * d**1.5  # noqa: E731
    look = make_lookup(_map(hertz), "powerlaw")
    for d in (2.2, 3.7, 4.9, 6.1):
        assert look(10.0, 0.0, d)[0] == pytest.approx(hertz(10.0, 0.0, d), rel=1e-12)


def test_nearest_returns_node_values():
    m = _map()
    look = make_lookup(m, "nearest")
    assert look(X0 + 3 * DX + 0.3 * DX, Y0 + 2 * DY - 0.4 * DY, 4.4)[0] == pytest.approx(
        _linear_field(X0 + 3 * DX, Y0 + 2 * DY, 4.5)
    )


@pytest.mark.parametrize("interpolation", INTERPOLATIONS)
def test_outside_the_map_is_zero_or_the_edge_never_extrapolated(interpolation):
    m = _map()
    x0, x1, y0, y1 = m.extent_mm
    zero = make_lookup(m, interpolation, "zero")
    clamp = make_lookup(m, interpolation, "clamp")
    for x, y in [(x0 - 0.01, 0.0), (x1 + 5, 0.0), (10.0, y0 - 1), (10.0, y1 + 0.01)]:
        assert zero(x, y, 4.0) == (0.0, 0.0)
        edge = clamp(min(max(x, x0), x1), min(max(y, y0), y1), 4.0)
        assert clamp(x, y, 4.0) == pytest.approx(edge)


@pytest.mark.parametrize("interpolation", INTERPOLATIONS)
def test_depths_outside_the_table(interpolation):
    m = _map()
    look = make_lookup(m, interpolation)
    x, y = X0 + 10 * DX, Y0 + 5 * DY  # a node, so every variant agrees there
    at_first = look(x, y, DEPTHS[0])[0]
    assert look(x, y, 0.0) == (0.0, 0.0) and look(x, y, -1.0) == (0.0, 0.0)
    assert look(x, y, DEPTHS[0] / 4)[0] == pytest.approx(at_first / 4)  # ramp from 0 N at 0 mm
    deepest = look(x, y, DEPTHS[-1])[0]
    assert look(x, y, DEPTHS[-1] + 10.0)[0] == pytest.approx(deepest)  # held, not extrapolated


def _renderer(m=None, **kw):
    return ForceRenderer(m or _map(), _flat_mesh(), RenderParams(**kw))


def test_normal_force_along_contact_normal_and_zero_above_surface():
    r = _renderer(horizontal="off")
    assert r.render(10.0, 3.0, 20.5)[:3] == (0.0, 0.0, 0.0)
    fx, fy, fz, fn, fh, depth, contact, retracting = r.render(10.0, 3.0, 16.0)
    assert contact and not retracting and depth == pytest.approx(4.0)
    assert (fx, fy) == (0.0, 0.0) and fz == pytest.approx(_linear_field(10.0, 3.0, 4.0)) and fz == fn


def test_no_normal_force_while_depth_decreases():
    r = _renderer(horizontal="off", retract_deadband_mm=0.02)
    for z in np.linspace(19.0, 15.0, 41):  # pressing in
        out = r.render(10.0, 3.0, float(z))
    assert out[2] > 0 and not out[7]
    out = r.render(10.0, 3.0, 15.01)  # 0.01 mm back: inside the deadband, still pressing
    assert out[2] > 0
    for z in np.linspace(15.05, 17.0, 20):  # retracting: no normal force at all
        out = r.render(10.0, 3.0, float(z))
        assert out[7] and out[2] == 0.0 and out[3] == 0.0
    out = r.render(10.0, 3.0, 16.9)  # pressing again
    assert not out[7] and out[2] > 0
    r2 = _renderer(horizontal="off", release_on_retract=False)
    r2.render(10.0, 3.0, 15.0)
    assert r2.render(10.0, 3.0, 16.0)[2] > 0  # seed 002 style: the force stays on


def test_clamp_at_max_force():
    strong = _map(lambda x, y, d: 1.0 * d)  # 7 N at 7 mm, horizontal 0.7 N
    r = ForceRenderer(strong, _flat_mesh(), RenderParams(max_force_n=3.3, horizontal="off"))
    fz = r.render(10.0, 3.0, 12.0)[2]
    assert fz == pytest.approx(3.3)
    r = ForceRenderer(strong, _flat_mesh(), RenderParams(max_force_n=3.3))
    r.render(5.0, 3.0, 12.0)
    fx, fy, fz, fn, fh, *_ = r.render(10.0, 3.0, 12.0)  # moving +x: 3.3 N normal (clamped) + 0.7 N horizontal
    assert fn == pytest.approx(3.3) and fh == pytest.approx(0.7)  # depth 8 mm: the 7 mm matrix is held
    assert math.sqrt(fx * fx + fy * fy + fz * fz) == pytest.approx(3.3)  # the total is clamped too
    assert fx < 0  # the horizontal reaction resists the motion


def test_horizontal_force_follows_the_projected_motion():
    r = _renderer()
    r.render(10.0, 3.0, 16.0)
    out = r.render(10.0, 3.2, 16.0)  # moving +y by 0.2 mm (above min_motion_mm)
    fh = out[4]
    assert out[1] == pytest.approx(-fh) and out[0] == pytest.approx(0.0)
    r = _renderer(horizontal="along")
    r.render(10.0, 3.0, 16.0)
    out = r.render(10.2, 3.0, 16.0)
    assert out[0] == pytest.approx(out[4])
    still = _renderer()
    assert still.render(10.0, 3.0, 16.0)[0:2] == (0.0, 0.0)  # no motion yet: no direction, no horizontal force


def test_orientation_rotates_the_tissue_and_its_forces():
    m = _map(lambda x, y, d: 0.5 + 0.05 * x + 0.0 * y + 0.1 * d)
    mesh = SurfaceMesh.from_height_grid(
        [0.0, 10.0, 40.0], [-10.0, 40.0], np.array([[20, 20], [20, 20], [30, 30]], float)
    )
    place = Placement(90.0, (20.0, 15.0))
    rot = ForceRenderer(m, mesh, RenderParams(horizontal="off"), place)
    ref = ForceRenderer(m, mesh, RenderParams(horizontal="off"))
    local = (25.0, 6.0, 21.0)
    world = place.to_world(*local)
    a = rot.render(*world)
    b = ref.render(*local)
    assert a[3:6] == pytest.approx(b[3:6])
    # the local force (bx, by) rotated by +90° is (−by, bx)
    assert (a[0], a[1], a[2]) == pytest.approx((-b[1], b[0], b[2]))
    assert place.to_local(*place.to_world(3.0, 4.0, 5.0)) == pytest.approx((3.0, 4.0, 5.0))


def test_reference_matches_on_smooth_field():
    m = _map(lambda x, y, d: 0.2 + 0.001 * x**2 + 0.01 * y + 0.02 * d**2)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(6, 30, 50), rng.uniform(-3, 30, 50), rng.uniform(2, 7, 50)])
    got = reference_forces(m, pts)
    np.testing.assert_allclose(got, 0.2 + 0.001 * pts[:, 0] ** 2 + 0.01 * pts[:, 1] + 0.02 * pts[:, 2] ** 2, rtol=1e-4)


def test_bad_render_parameters():
    with pytest.raises(ModelParameterError, match="interpolation is 'spline'"):
        RenderParams(interpolation="spline").validate()
    with pytest.raises(ModelParameterError, match="max_force_n"):
        RenderParams(max_force_n=-1).validate()
    with pytest.raises(ModelParameterError, match="outside"):
        RenderParams(outside="extrapolate").validate()
