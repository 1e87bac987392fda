"""Seed 002's surface from a depth-sensor point cloud: table-plane segmentation (RANSAC), PCA alignment and
linear re-gridding onto the height grid a :class:`~studyctl.models.surface_mesh.SurfaceMesh` triangulates.

Run once per phantom when a scene is built, never in the force loop (queries are the mesh's business).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.models.surface_mesh import SurfaceMesh


@dataclass(frozen=True, eq=False)
class PointCloudSurface:
    """A surface reconstructed from a point cloud, with the transform that aligned it.

    ``rotation`` and ``translation`` map cloud coordinates to the mesh frame: ``p_mesh = R @ p + t``. In
    the mesh frame the table plane is z = 0, z points up into the tissue side, the tissue points' principal
    axis is x and their centroid is at x = y = 0.
    """

    mesh: SurfaceMesh
    rotation: np.ndarray
    translation: np.ndarray
    plane_normal: np.ndarray
    plane_offset: float
    table_fraction: float
    n_surface_points: int


def _fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    n = vt[-1]
    return n, float(-n @ centroid)


def surface_from_point_cloud(
    points: Any,
    rng: np.random.Generator,
    *,
    grid_shape: tuple[int, int] = (31, 26),
    plane_tolerance_mm: float = 1.0,
    min_table_fraction: float = 0.2,
    iterations: int = 300,
    min_surface_points: int = 30,
) -> PointCloudSurface:
    """Seed 002's reconstruction: segment the table plane (RANSAC), align, re-grid, triangulate.

    Steps: RANSAC picks the plane with most points within ``plane_tolerance_mm`` (refined by least squares
    on its inliers); the points farther than the tolerance on the side holding most of them are the
    tissue; the table normal becomes +z, the tissue centroid the xy origin and the first principal axis
    of the tissue points x; heights are linearly interpolated onto a regular ``grid_shape`` grid over the
    tissue's bounding box (0, the table, outside the points' convex hull).

    Raises
    ------
    ModelParameterError
        Malformed points, no plane holding ``min_table_fraction`` of them (no table in the cloud), or fewer
        than ``min_surface_points`` points above the plane.
    """
    from scipy.interpolate import griddata

    if not isinstance(rng, np.random.Generator):
        raise ModelParameterError("point cloud: rng must be a numpy.random.Generator (seeded by the caller)")
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 10:
        raise ModelParameterError(f"point cloud: expected an (n, 3) array with n ≥ 10, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ModelParameterError(
            f"point cloud: row {int(np.argwhere(~np.isfinite(pts))[0][0])} is NaN/inf; drop invalid depth pixels first"
        )
    gx, gy = (int(v) for v in grid_shape)
    if gx < 2 or gy < 2:
        raise ModelParameterError(f"point cloud: grid_shape {grid_shape} needs at least 2 × 2 nodes")
    n = pts.shape[0]
    best_count, best_plane = -1, None
    for _ in range(int(iterations)):
        sample = pts[rng.choice(n, 3, replace=False)]
        normal = np.cross(sample[1] - sample[0], sample[2] - sample[0])
        norm = np.linalg.norm(normal)
        if norm < 1e-12:
            continue
        normal /= norm
        dist = np.abs((pts - sample[0]) @ normal)
        count = int((dist <= plane_tolerance_mm).sum())
        if count > best_count:
            best_count, best_plane = count, (normal, float(-normal @ sample[0]))
    fraction = best_count / n
    if best_plane is None or fraction < min_table_fraction:
        raise ModelParameterError(
            f"point cloud has no table plane: the best plane holds {max(fraction, 0.0):.1%} of {n} points within "
            f"{plane_tolerance_mm} mm, below min_table_fraction {min_table_fraction:.0%}; include the table around "
            "the tissue in the scan or raise plane_tolerance_mm"
        )
    normal, offset = best_plane
    inliers = np.abs(pts @ normal + offset) <= plane_tolerance_mm
    normal, offset = _fit_plane(pts[inliers])
    signed = pts @ normal + offset
    above, below = signed > plane_tolerance_mm, signed < -plane_tolerance_mm
    if below.sum() > above.sum():
        normal, offset, signed = -normal, -offset, -signed
        above = signed > plane_tolerance_mm
    tissue = pts[above]
    if tissue.shape[0] < min_surface_points:
        raise ModelParameterError(
            f"point cloud: only {tissue.shape[0]} points lie more than {plane_tolerance_mm} mm above the table plane; "
            f"need ≥ {min_surface_points} to reconstruct a surface"
        )
    # Rotate the table normal onto +z (Rodrigues), then the tissue's first principal axis onto x.
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(normal, z)
    s, c = np.linalg.norm(v), float(normal @ z)
    if s < 1e-12:
        r1 = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        r1 = np.eye(3) + vx + vx @ vx * ((1 - c) / s**2)
    t1 = np.array([0.0, 0.0, offset])  # table plane n·p + offset = 0 → z = 0 after rotation
    aligned = tissue @ r1.T + t1
    centroid = aligned[:, :2].mean(axis=0)
    cov = np.cov((aligned[:, :2] - centroid).T)
    evals, evecs = np.linalg.eigh(cov)
    axis = evecs[:, int(np.argmax(evals))]
    if axis[int(np.argmax(np.abs(axis)))] < 0:
        axis = -axis  # a deterministic sign for the principal axis
    r2 = np.array([[axis[0], axis[1], 0.0], [-axis[1], axis[0], 0.0], [0.0, 0.0, 1.0]])
    rotation = r2 @ r1
    translation = r2 @ (t1 - np.array([centroid[0], centroid[1], 0.0]))
    local = tissue @ rotation.T + translation
    xs = np.linspace(local[:, 0].min(), local[:, 0].max(), gx)
    ys = np.linspace(local[:, 1].min(), local[:, 1].max(), gy)
    xg, yg = np.meshgrid(xs, ys, indexing="ij")
    heights = griddata(local[:, :2], local[:, 2], (xg, yg), method="linear", fill_value=0.0)
    mesh = SurfaceMesh.from_height_grid(xs, ys, heights, source="point cloud")
    return PointCloudSurface(mesh, rotation, translation, normal, float(offset), float(fraction), int(tissue.shape[0]))
