"""Exact indentation depth: the indexed nearest-triangle query against an independent brute force, near
faces, edges and vertices; the height field; point-cloud reconstruction and its bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.errors import ModelParameterError
from studyctl.models.point_cloud import surface_from_point_cloud
from studyctl.models.surface_mesh import SurfaceMesh
from studyctl.models.synthetic_phantom import curved_phantom_002


def _segment_distances(p, a, b):
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def _reference(mesh, p):
    """Independent reference, vectorised over all triangles: the distance to the plane where the point's
    projection falls inside (barycentric coordinates from the 2 × 2 normal equations, Cramer's rule),
    otherwise the nearest of the three edges."""
    tri = mesh.vertices[mesh.faces]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    p = np.broadcast_to(np.asarray(p, dtype=float), a.shape)
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    h = np.einsum("ij,ij->i", p - a, n)
    proj = p - h[:, None] * n
    e1, e2, r = b - a, c - a, proj - a
    m11, m12, m22 = (np.einsum("ij,ij->i", u, w) for u, w in ((e1, e1), (e1, e2), (e2, e2)))
    r1, r2 = np.einsum("ij,ij->i", r, e1), np.einsum("ij,ij->i", r, e2)
    det = m11 * m22 - m12 * m12
    v = (r1 * m22 - r2 * m12) / det
    w = (m11 * r2 - m12 * r1) / det
    inside = (v >= 0) & (w >= 0) & (v + w <= 1)
    edges = np.minimum(
        np.minimum(_segment_distances(p, a, b), _segment_distances(p, b, c)), _segment_distances(p, c, a)
    )
    return float(np.min(np.where(inside, np.abs(h), edges)))


@pytest.fixture(scope="module")
def bumpy():
    """A rough, non-uniformly spaced height grid: faces of very different sizes and slopes."""
    rng = np.random.default_rng(3)
    xs = np.cumsum(rng.uniform(1.0, 6.0, 12))
    ys = np.cumsum(rng.uniform(1.0, 6.0, 10))
    h = 10 + rng.normal(0, 2.5, (12, 10))
    return SurfaceMesh.from_height_grid(xs, ys, h, cell_mm=1.3)


@pytest.fixture(scope="module")
def curved():
    ph = curved_phantom_002(np.random.default_rng(0), noise_n=0.0)
    return SurfaceMesh.from_height_grid(ph.surface_xs_mm, ph.surface_ys_mm, ph.surface_heights_mm)


def test_seed002_grid_has_1500_triangles(curved):
    assert curved.vertices.shape == (31 * 26, 3)
    assert curved.n_faces == 1500
    assert np.all(curved.face_normals[:, 2] > 0)  # counter-clockwise from above: normals point out of the tissue


@pytest.mark.parametrize("which", ["bumpy", "curved"])
def test_exact_distance_random_points(which, request):
    mesh = request.getfixturevalue(which)
    rng = np.random.default_rng(11)
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    pts = rng.uniform(lo - 5, hi + 5, (150, 3))
    for p in pts:
        assert mesh.closest(p).distance_mm == pytest.approx(_reference(mesh, p), abs=1e-9)


@pytest.mark.parametrize("which", ["bumpy", "curved"])
def test_exact_distance_near_vertices_and_edges(which, request):
    mesh = request.getfixturevalue(which)
    rng = np.random.default_rng(12)
    tri = mesh.vertices[mesh.faces]
    pts = []
    for _ in range(80):  # next to a random vertex
        v = mesh.vertices[rng.integers(len(mesh.vertices))]
        pts.append(v + rng.normal(0, 0.05, 3))
    for _ in range(80):  # next to a random edge, on either side
        t = tri[rng.integers(len(tri))]
        a, b = t[rng.permutation(3)[:2]]
        pts.append(a + rng.uniform() * (b - a) + rng.normal(0, 0.2, 3))
    for _ in range(40):  # exactly on vertices and edge midpoints: distance 0
        t = tri[rng.integers(len(tri))]
        pts.append(t[0].copy())
        pts.append((t[1] + t[2]) / 2)
    for p in pts:
        got = mesh.closest(p)
        assert got.distance_mm == pytest.approx(_reference(mesh, np.asarray(p)), abs=1e-9)
        assert math.dist(got.point, p) == pytest.approx(got.distance_mm, abs=1e-9)


def test_indexed_query_matches_vectorised_brute_force(curved):
    rng = np.random.default_rng(5)
    xy = np.column_stack([rng.uniform(0, 90, 200), rng.uniform(0, 75, 200)])
    h = np.array([curved.height_at(*q) for q in xy])
    pts = np.column_stack([xy, h - rng.uniform(0, 8, 200)])
    fast = np.array([curved.closest_tuple(*p)[0] for p in pts.tolist()])
    np.testing.assert_allclose(fast, curved.brute_force_distance(pts), atol=1e-9)


def test_distance_not_from_nearest_vertex():
    """A point over the middle of one large triangle: all vertices are farther than the face."""
    mesh = SurfaceMesh.from_height_grid([0.0, 100.0], [0.0, 100.0], np.zeros((2, 2)), cell_mm=5.0)
    c = mesh.closest((70.0, 30.0, -3.0))
    assert c.distance_mm == pytest.approx(3.0)
    assert c.point == pytest.approx((70.0, 30.0, 0.0))
    assert c.normal == pytest.approx((0.0, 0.0, 1.0))


def test_indentation_contact_and_normal():
    # a ridge: two planes meeting at x = 10 (height 10), sloping down to 0 at x = 0 and x = 20
    mesh = SurfaceMesh.from_height_grid([0.0, 10.0, 20.0], [0.0, 20.0], np.array([[0, 0], [10, 10], [0, 0]], float))
    assert mesh.indentation(5.0, 10.0, 6.0) is None  # above the surface (height 5 there)
    assert mesh.indentation(-1.0, 10.0, -5.0) is None  # off the footprint
    d, qx, qy, qz, nx, ny, nz = mesh.indentation(5.0, 10.0, 4.0)
    assert d == pytest.approx(1.0 / math.sqrt(2.0))
    assert (nx, ny, nz) == pytest.approx((-1 / math.sqrt(2), 0.0, 1 / math.sqrt(2)))
    # straight under the ridge line the nearest point is the ridge (an edge): normal points straight up
    d, qx, qy, qz, nx, ny, nz = mesh.indentation(10.0, 10.0, 7.0)
    assert d == pytest.approx(3.0 / math.sqrt(2.0)) and nz > 0.7


def test_height_at_is_the_triangulated_surface(bumpy):
    rng = np.random.default_rng(2)
    x0, x1, y0, y1 = bumpy.footprint_mm
    for _ in range(200):
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        h = bumpy.height_at(x, y)
        f = bumpy.face_under(x, y)
        a = bumpy.vertices[bumpy.faces[f, 0]]
        n = bumpy.face_normals[f]
        assert np.dot(np.array([x, y, h]) - a, n) == pytest.approx(0.0, abs=1e-9)
    assert bumpy.height_at(x0 - 1, y0) is None


def test_bad_height_grids():
    with pytest.raises(ModelParameterError, match="strictly increasing"):
        SurfaceMesh.from_height_grid([0, 2, 1], [0, 1], np.zeros((3, 2)))
    with pytest.raises(ModelParameterError, match=r"shape \(2, 2\); expected \(3, 2\)"):
        SurfaceMesh.from_height_grid([0, 1, 2], [0, 1], np.zeros((2, 2)))
    with pytest.raises(ModelParameterError, match="NaN/inf node at row 1, column 0"):
        SurfaceMesh.from_height_grid([0, 1], [0, 1], np.array([[0, 0], [np.nan, 0]]))


def _rigid(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q, rng.normal(0, 200, 3)


@pytest.mark.slow
def test_point_cloud_reconstruction_recovers_the_dome():
    rng = np.random.default_rng(8)
    # a 90 × 50 mm dome (long axis along x), 20 mm high, on a table extending 40 mm around it
    u = rng.uniform(-45, 45, 6000)
    v = rng.uniform(-25, 25, 6000)
    h = 20.0 * (1 - (u / 45) ** 2) * (1 - (v / 25) ** 2) + 1.5
    tissue = np.column_stack([u, v, h + rng.normal(0, 0.2, u.size)])
    tx, ty = rng.uniform(-85, 85, 8000), rng.uniform(-65, 65, 8000)
    off = (np.abs(tx) > 46) | (np.abs(ty) > 26)
    table = np.column_stack([tx[off], ty[off], rng.normal(0, 0.2, off.sum())])
    cloud = np.vstack([tissue, table])
    rot, shift = _rigid(rng)
    cloud = cloud @ rot.T + shift
    out = surface_from_point_cloud(cloud, np.random.default_rng(0), grid_shape=(31, 26), iterations=100)
    mesh = out.mesh
    assert mesh.heights_mm.shape == (31, 26)
    assert out.table_fraction > 0.4
    x0, x1, y0, y1 = mesh.footprint_mm
    assert x1 - x0 == pytest.approx(90.0, abs=2.0)  # the long axis became x
    assert y1 - y0 == pytest.approx(50.0, abs=2.0)
    assert mesh.heights_mm.max() == pytest.approx(21.5, abs=1.0)
    # the dome's shape comes back (up to the 180° ambiguity of the principal axis, which it is symmetric under)
    centre = mesh.height_at(0.0, 0.0)
    assert centre == pytest.approx(21.5, abs=1.0)
    assert mesh.height_at(30.0, 0.0) == pytest.approx(20 * (1 - (30 / 45) ** 2) + 1.5, abs=1.0)


def test_point_cloud_without_a_plane_is_refused():
    rng = np.random.default_rng(1)
    blob = rng.normal(0, 30, (3000, 3))  # a cloud with no table in it
    with pytest.raises(ModelParameterError, match="point cloud has no table plane"):
        surface_from_point_cloud(blob, np.random.default_rng(0))
    flat = np.column_stack([rng.uniform(0, 100, 500), rng.uniform(0, 100, 500), np.zeros(500)])
    with pytest.raises(ModelParameterError, match="only 0 points lie more than"):
        surface_from_point_cloud(flat, np.random.default_rng(0))
    with pytest.raises(ModelParameterError, match=r"expected an \(n, 3\) array"):
        surface_from_point_cloud(np.zeros((5, 2)), np.random.default_rng(0))
