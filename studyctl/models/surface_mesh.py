"""Tissue surface as a triangle mesh over a regular height grid, and exact indentation depth.

Seed 002 reconstructs the phantom surface from a depth-sensor point cloud (table-plane segmentation,
PCA alignment, linear re-gridding) and displays it as 1500 triangles over 31 × 26 nodes; the indentation
depth is the distance from the indenter to the nearest triangle of the undeformed surface. This module
builds that mesh (:meth:`SurfaceMesh.from_height_grid`; from a scan: :mod:`studyctl.models.point_cloud`) and answers
depth queries exactly (:meth:`SurfaceMesh.closest`, :meth:`SurfaceMesh.indentation`).

Exactness and speed
-------------------
The nearest point may lie inside a large triangle whose vertices are all farther away, or on an edge or
vertex; nearest-vertex shortcuts are wrong there. Queries use a uniform 3-D grid of cells of side ``s``.
For a cell with centre ``c`` and half-diagonal ``r`` the candidate triangles are those with
``dist(c, T) ≤ min_T dist(c, T) + 2r``: for any query ``p`` in the cell, its nearest triangle ``T*``
satisfies ``dist(c, T*) ≤ dist(p, T*) + r ≤ dist(p, T_c) + r ≤ dist(c, T_c) + 2r``, so ``T*`` is always a
candidate. Candidate lists are built on first use of a cell (exact vectorised distances over the faces a
``scipy.spatial.cKDTree`` of face centroids returns within a provable radius) and cached; a query is then
a dictionary look-up plus a few point–triangle distances on plain Python floats, pruned by the distance
to each triangle's plane (a lower bound).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from studyctl.errors import ModelParameterError


def closest_points_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest point of each triangle ``(a[i], b[i], c[i])`` to ``p`` (broadcast), by Voronoi regions.

    Parameters
    ----------
    p : array (..., 3)
    a, b, c : arrays (..., 3), the triangles' vertices

    Returns
    -------
    ndarray (..., 3)
    """
    p, a, b, c = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (p, a, b, c)))
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("...i,...i->...", ab, ap)
    d2 = np.einsum("...i,...i->...", ac, ap)
    abab = np.einsum("...i,...i->...", ab, ab)
    abac = np.einsum("...i,...i->...", ab, ac)
    acac = np.einsum("...i,...i->...", ac, ac)
    d3, d4 = d1 - abab, d2 - abac  # ab·(p−b), ac·(p−b)
    d5, d6 = d1 - abac, d2 - acac  # ab·(p−c), ac·(p−c)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_face = np.where(denom != 0, vb / denom, 0.0)
        w_face = np.where(denom != 0, vc / denom, 0.0)
        t_ab = np.where(d1 - d3 != 0, d1 / (d1 - d3), 0.0)
        t_ac = np.where(d2 - d6 != 0, d2 / (d2 - d6), 0.0)
        t_bc = np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) / ((d4 - d3) + (d5 - d6)), 0.0)
    out = a + ab * v_face[..., None] + ac * w_face[..., None]
    # Assign regions in reverse priority so that the first matching test of Ericson's algorithm wins.
    region_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    out = np.where(region_bc[..., None], b + (c - b) * t_bc[..., None], out)
    region_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    out = np.where(region_ac[..., None], a + ac * t_ac[..., None], out)
    region_c = (d6 >= 0) & (d5 <= d6)
    out = np.where(region_c[..., None], c, out)
    region_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    out = np.where(region_ab[..., None], a + ab * t_ab[..., None], out)
    region_b = (d3 >= 0) & (d4 <= d3)
    out = np.where(region_b[..., None], b, out)
    region_a = (d1 <= 0) & (d2 <= 0)
    out = np.where(region_a[..., None], a, out)
    return out


@dataclass(frozen=True)
class Contact:
    """Nearest point of the surface to a query: distance (mm), the point, the face and the unit normal.

    ``normal`` points from the query towards the surface point when they differ (for a probe inside the
    tissue: the direction the tissue pushes it), otherwise the face's upward normal.
    """

    distance_mm: float
    point: tuple[float, float, float]
    face: int
    normal: tuple[float, float, float]


@dataclass(eq=False)
class SurfaceMesh:
    """A height-field triangle mesh: nodes on a regular (x, y) grid, two triangles per cell.

    Build with :meth:`from_height_grid`. ``heights_mm[i, j]`` is the height above the table at
    ``(xs_mm[i], ys_mm[j])``. Cell ``(i, j)`` is split along its (i, j)–(i+1, j+1) diagonal; all faces are
    counter-clockwise seen from above, so face normals point up (out of the tissue).
    """

    xs_mm: np.ndarray
    ys_mm: np.ndarray
    heights_mm: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    face_normals: np.ndarray
    cell_mm: float
    _cells: dict[tuple[int, int, int], tuple[tuple[float, ...], ...]] = field(default_factory=dict, repr=False)
    _tree: Any = field(default=None, repr=False)
    _face_tuples: list[tuple[float, ...]] = field(default_factory=list, repr=False)
    _circum: float = 0.0

    # ------------------------------------------------------------------------------------------ build

    @classmethod
    def from_height_grid(
        cls, xs_mm: Any, ys_mm: Any, heights_mm: Any, *, cell_mm: float | None = None, source: str = "height grid"
    ) -> SurfaceMesh:
        """Triangulate a height grid (e.g. seed 002's 31 × 26 nodes → 1500 triangles).

        Parameters
        ----------
        xs_mm, ys_mm : 1-D arrays, strictly increasing node coordinates (≥ 2 each)
        heights_mm : array (len(xs_mm), len(ys_mm)), finite heights above the table
        cell_mm : side of the query-index cells; default half the shortest grid spacing
        """
        xs = np.asarray(xs_mm, dtype=float).reshape(-1)
        ys = np.asarray(ys_mm, dtype=float).reshape(-1)
        h = np.asarray(heights_mm, dtype=float)
        for name, arr in (("xs_mm", xs), ("ys_mm", ys)):
            if arr.size < 2 or not np.all(np.isfinite(arr)) or np.any(np.diff(arr) <= 0):
                raise ModelParameterError(
                    f"surface {source}: field {name!r} must hold ≥ 2 finite, strictly increasing node coordinates"
                )
        if h.shape != (xs.size, ys.size):
            raise ModelParameterError(
                f"surface {source}: field 'heights_mm' has shape {h.shape}; expected ({xs.size}, {ys.size}) "
                "= (len(xs_mm), len(ys_mm))"
            )
        if not np.all(np.isfinite(h)):
            i, j = (int(v) for v in np.argwhere(~np.isfinite(h))[0])
            raise ModelParameterError(f"surface {source}: field 'heights_mm' has a NaN/inf node at row {i}, column {j}")
        nx, ny = xs.size, ys.size
        xg, yg = np.meshgrid(xs, ys, indexing="ij")
        vertices = np.stack([xg.ravel(), yg.ravel(), h.ravel()], axis=1)
        idx = np.arange(nx * ny).reshape(nx, ny)
        v00, v10 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
        v01, v11 = idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
        # Faces of cell (i, j) sit at 2·(i·(ny−1) + j) and +1, so the face under a point is O(1) to find.
        faces = np.empty((2 * v00.size, 3), dtype=np.int64)
        faces[0::2] = np.stack([v00, v10, v11], axis=1)
        faces[1::2] = np.stack([v00, v11, v01], axis=1)
        if cell_mm is None:
            cell_mm = 0.5 * float(min(np.diff(xs).min(), np.diff(ys).min()))
        if not (math.isfinite(cell_mm) and cell_mm > 0):
            raise ModelParameterError(f"surface {source}: cell_mm is {cell_mm!r}; it must be a positive length")
        tri = vertices[faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        for arr in (xs, ys, h, vertices, faces, n):
            arr.setflags(write=False)
        mesh = cls(xs, ys, h, vertices, faces, n, float(cell_mm))
        mesh._prepare()
        return mesh

    def _prepare(self) -> None:
        tri = self.vertices[self.faces]
        centroids = tri.mean(axis=1)
        self._tree = cKDTree(centroids)
        self._circum = float(np.linalg.norm(tri - centroids[:, None, :], axis=2).max())
        ab = tri[:, 1] - tri[:, 0]
        ac = tri[:, 2] - tri[:, 0]
        rows = []
        for f in range(len(self.faces)):
            a = tri[f, 0]
            rows.append(
                (
                    *map(float, a),
                    *map(float, ab[f]),
                    *map(float, ac[f]),
                    *map(float, self.face_normals[f]),
                    float(ab[f] @ ab[f]),
                    float(ab[f] @ ac[f]),
                    float(ac[f] @ ac[f]),
                    float(f),
                )
            )
        self._face_tuples = rows
        self._x0, self._y0 = float(self.xs_mm[0]), float(self.ys_mm[0])
        self._x1, self._y1 = float(self.xs_mm[-1]), float(self.ys_mm[-1])
        self._xs_list = [float(v) for v in self.xs_mm]
        self._ys_list = [float(v) for v in self.ys_mm]
        self._h_list = [[float(v) for v in row] for row in self.heights_mm]
        steps_x, steps_y = np.diff(self.xs_mm), np.diff(self.ys_mm)
        self._uniform = bool(np.allclose(steps_x, steps_x[0]) and np.allclose(steps_y, steps_y[0]))
        self._dx, self._dy = float(steps_x[0]), float(steps_y[0])
        lo = self.vertices.min(axis=0)
        self._origin = (float(lo[0]), float(lo[1]), float(lo[2]))
        self._inv_cell = 1.0 / self.cell_mm
        self._nx1 = len(self._xs_list) - 2  # the last cell index along x and y
        self._ny1 = len(self._ys_list) - 2
        # The last indentation query and its answer: a probe held still (a dwell, a quantised encoder that did
        # not tick) asks the same point again, about one tick in five in the palpation studies.
        self._last_query: tuple[float, float, float, Any] = (math.nan, math.nan, math.nan, None)

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def footprint_mm(self) -> tuple[float, float, float, float]:
        return (float(self.xs_mm[0]), float(self.xs_mm[-1]), float(self.ys_mm[0]), float(self.ys_mm[-1]))

    def to_frame(self) -> pd.DataFrame:
        """Faces: columns face, v0, v1, v2, nx, ny, nz."""
        return pd.DataFrame(
            {
                "face": np.arange(self.n_faces),
                "v0": self.faces[:, 0],
                "v1": self.faces[:, 1],
                "v2": self.faces[:, 2],
                "nx": self.face_normals[:, 0],
                "ny": self.face_normals[:, 1],
                "nz": self.face_normals[:, 2],
            }
        )

    # ------------------------------------------------------------------------------------- height field

    def _cell_of(self, x: float, y: float) -> tuple[int, int] | None:
        if x < self._x0 or x > self._x1 or y < self._y0 or y > self._y1:
            return None
        nx1 = self._nx1
        ny1 = self._ny1
        if self._uniform:
            i = min(int((x - self._x0) / self._dx), nx1)
            j = min(int((y - self._y0) / self._dy), ny1)
        else:
            import bisect

            i = min(max(bisect.bisect_right(self._xs_list, x) - 1, 0), nx1)
            j = min(max(bisect.bisect_right(self._ys_list, y) - 1, 0), ny1)
        return i, j

    def height_at(self, x: float, y: float) -> float | None:
        """Surface height at (x, y) on the triangle under it, or None outside the footprint."""
        if self._uniform:
            # _cell_of's uniform case inline (this runs every tick of a palpation trial)
            gx0, gy0 = self._x0, self._y0
            if x < gx0 or x > self._x1 or y < gy0 or y > self._y1:
                return None
            i = int((x - gx0) / self._dx)
            if i > self._nx1:
                i = self._nx1
            j = int((y - gy0) / self._dy)
            if j > self._ny1:
                j = self._ny1
        else:
            cell = self._cell_of(x, y)
            if cell is None:
                return None
            i, j = cell
        xs, ys = self._xs_list, self._ys_list
        x0, x1 = xs[i], xs[i + 1]
        y0, y1 = ys[j], ys[j + 1]
        u = (x - x0) / (x1 - x0)
        v = (y - y0) / (y1 - y0)
        h = self._h_list
        h00, h10, h01, h11 = h[i][j], h[i + 1][j], h[i][j + 1], h[i + 1][j + 1]
        if u >= v:  # triangle (00, 10, 11)
            return h00 + u * (h10 - h00) + v * (h11 - h10)
        return h00 + v * (h01 - h00) + u * (h11 - h01)  # triangle (00, 11, 01)

    def face_under(self, x: float, y: float) -> int | None:
        """Index of the face whose xy-projection holds (x, y), or None outside the footprint."""
        cell = self._cell_of(x, y)
        if cell is None:
            return None
        i, j = cell
        u = (x - self._xs_list[i]) / (self._xs_list[i + 1] - self._xs_list[i])
        v = (y - self._ys_list[j]) / (self._ys_list[j + 1] - self._ys_list[j])
        base = 2 * (i * (len(self._ys_list) - 1) + j)
        return base if u >= v else base + 1

    # ------------------------------------------------------------------------------------ exact distance

    def _cell_candidates(self, key: tuple[int, int, int]) -> tuple[tuple[float, ...], ...]:
        self._build_cells([key])
        return self._cells[key]

    def _build_cells(self, keys: list[tuple[int, int, int]]) -> None:
        """Candidate lists of many cells at once (vectorised over cells × nearby faces)."""
        if not keys:
            return
        s = self.cell_mm
        karr = np.asarray(keys, dtype=float)
        centres = np.asarray(self._origin)[None, :] + (karr + 0.5) * s
        r = 0.5 * math.sqrt(3.0) * s
        tri = self.vertices[self.faces]
        k = min(8, self.n_faces)
        _, near = self._tree.query(centres, k=k)
        near = near.reshape(len(keys), k)
        q = closest_points_on_triangles(centres[:, None, :], tri[near, 0], tri[near, 1], tri[near, 2])
        d_up = np.linalg.norm(q - centres[:, None, :], axis=2).min(axis=1)
        balls = self._tree.query_ball_point(centres, d_up + 2.0 * r + self._circum + 1e-9)
        lengths = np.fromiter((len(b) for b in balls), dtype=np.int64, count=len(keys))
        cell_of = np.repeat(np.arange(len(keys)), lengths)
        face_of = np.fromiter((f for b in balls for f in b), dtype=np.int64, count=int(lengths.sum()))
        q = closest_points_on_triangles(centres[cell_of], tri[face_of, 0], tri[face_of, 1], tri[face_of, 2])
        d = np.linalg.norm(q - centres[cell_of], axis=1)
        dmin = np.full(len(keys), np.inf)
        np.minimum.at(dmin, cell_of, d)
        keep = d <= dmin[cell_of] + 2.0 * r + 1e-9
        cell_k, face_k, d_k = cell_of[keep], face_of[keep], d[keep]
        order = np.lexsort((d_k, cell_k))  # by cell, nearest candidate first (prunes the rest sooner)
        cell_k, face_k = cell_k[order], face_k[order]
        bounds = np.searchsorted(cell_k, np.arange(len(keys) + 1))
        rows = self._face_tuples
        for n, key in enumerate(keys):
            self._cells[key] = tuple(rows[int(f)] for f in face_k[bounds[n] : bounds[n + 1]])

    def warm(self, max_depth_mm: float, above_mm: float = 1.0) -> int:
        """Build the candidate lists of every cell a probe can reach from ``above_mm`` above the surface to
        ``max_depth_mm`` below it, so that no query inside a trial pays for a cold cell. Returns the count."""
        s = self.cell_mm
        o = self._origin
        x0, x1, y0, y1 = self.footprint_mm
        ix = np.arange(math.floor((x0 - o[0]) / s), math.floor((x1 - o[0]) / s) + 1)
        iy = np.arange(math.floor((y0 - o[1]) / s), math.floor((y1 - o[1]) / s) + 1)
        keys: set[tuple[int, int, int]] = set()
        for i in ix:
            for j in iy:
                # Heights over the cell's xy square: sample its corners and centre, clamped to the footprint.
                hs = []
                for fx in (0.0, 0.5, 1.0):
                    for fy in (0.0, 0.5, 1.0):
                        x = min(max(o[0] + (i + fx) * s, x0), x1)
                        y = min(max(o[1] + (j + fy) * s, y0), y1)
                        hs.append(self.height_at(x, y))
                lo = min(hs) - max_depth_mm - s
                hi = max(hs) + above_mm
                for kz in range(math.floor((lo - o[2]) / s), math.floor((hi - o[2]) / s) + 1):
                    key = (int(i), int(j), int(kz))
                    if key not in self._cells:
                        keys.add(key)
        ordered = sorted(keys)
        for start in range(0, len(ordered), 4096):
            self._build_cells(ordered[start : start + 4096])
        return len(ordered)

    def closest_tuple(
        self, x: float, y: float, z: float
    ) -> tuple[float, float, float, float, int, float, float, float]:
        """Hot-path form of :meth:`closest`: ``(distance, qx, qy, qz, face, fnx, fny, fnz)``.

        ``fn*`` is the nearest face's normal (the contact normal in its interior).
        """
        inv = self._inv_cell
        o = self._origin
        key = (math.floor((x - o[0]) * inv), math.floor((y - o[1]) * inv), math.floor((z - o[2]) * inv))
        cands = self._cells.get(key)
        if cands is None:
            cands = self._cell_candidates(key)
        best2 = math.inf
        bq = (0.0, 0.0, 0.0)
        bf = cands[0]
        for t in cands:
            ax, ay, az, abx, aby, abz, acx, acy, acz, nx, ny, nz, abab, abac, acac, _f = t
            apx, apy, apz = x - ax, y - ay, z - az
            plane = apx * nx + apy * ny + apz * nz
            if plane * plane >= best2:
                continue  # the plane distance bounds the triangle distance from below
            d1 = abx * apx + aby * apy + abz * apz
            d2 = acx * apx + acy * apy + acz * apz
            if d1 <= 0.0 and d2 <= 0.0:
                qx, qy, qz = ax, ay, az
            else:
                d3, d4 = d1 - abab, d2 - abac
                d5, d6 = d1 - abac, d2 - acac
                vc = d1 * d4 - d3 * d2
                vb = d5 * d2 - d1 * d6
                va = d3 * d6 - d5 * d4
                if d3 >= 0.0 and d4 <= d3:
                    qx, qy, qz = ax + abx, ay + aby, az + abz
                elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                    v = d1 / (d1 - d3)
                    qx, qy, qz = ax + v * abx, ay + v * aby, az + v * abz
                elif d6 >= 0.0 and d5 <= d6:
                    qx, qy, qz = ax + acx, ay + acy, az + acz
                elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                    w = d2 / (d2 - d6)
                    qx, qy, qz = ax + w * acx, ay + w * acy, az + w * acz
                elif va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
                    w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
                    qx = ax + abx + w * (acx - abx)
                    qy = ay + aby + w * (acy - aby)
                    qz = az + abz + w * (acz - abz)
                else:
                    inv_den = 1.0 / (va + vb + vc)
                    v, w = vb * inv_den, vc * inv_den
                    qx = ax + abx * v + acx * w
                    qy = ay + aby * v + acy * w
                    qz = az + abz * v + acz * w
            ex, ey, ez = qx - x, qy - y, qz - z
            d2sq = ex * ex + ey * ey + ez * ez
            if d2sq < best2:
                best2, bq, bf = d2sq, (qx, qy, qz), t
        return (math.sqrt(best2), bq[0], bq[1], bq[2], int(bf[15]), bf[9], bf[10], bf[11])

    def closest(self, point: Any) -> Contact:
        """Exact nearest point of the mesh to ``point`` (x, y, z in mm)."""
        x, y, z = (float(v) for v in point)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise ModelParameterError(f"surface query point {point!r} is not finite")
        d, qx, qy, qz, face, fnx, fny, fnz = self.closest_tuple(x, y, z)
        if d > 1e-9:
            normal = ((qx - x) / d, (qy - y) / d, (qz - z) / d)
        else:
            normal = (fnx, fny, fnz)
        return Contact(d, (qx, qy, qz), face, normal)

    def indentation(
        self, x: float, y: float, z: float
    ) -> tuple[float, float, float, float, float, float, float] | None:
        """Contact of a probe at (x, y, z): None when it is above the surface or outside the footprint.

        Returns ``(depth, qx, qy, qz, nx, ny, nz)``: depth is the exact distance to the nearest triangle of
        the undeformed surface (seed 002), ``q`` that nearest point, ``n`` the unit contact normal pointing
        out of the tissue (from the probe to ``q``; the face normal when the two coincide).
        """
        last = self._last_query
        # Equal non-zero floats have equal bits (a zero may be -0.0), so a hit returns exactly what a new query
        # would: the mesh never changes.
        if x == last[0] and y == last[1] and z == last[2] and x and y and z:
            return last[3]
        h = self.height_at(x, y)
        if h is None or z >= h:
            hit = None
        else:
            d, qx, qy, qz, _face, fnx, fny, fnz = self.closest_tuple(x, y, z)
            if d > 1e-9:
                inv = 1.0 / d
                hit = (d, qx, qy, qz, (qx - x) * inv, (qy - y) * inv, (qz - z) * inv)
            else:
                hit = (d, qx, qy, qz, fnx, fny, fnz)
        self._last_query = (x, y, z, hit)  # one tuple, replaced whole: safe to read from another thread
        return hit

    def brute_force_distance(self, points: Any) -> np.ndarray:
        """Distance from each point to every triangle, minimised (O(n·m) reference for tests)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        tri = self.vertices[self.faces]
        q = closest_points_on_triangles(pts[:, None, :], tri[None, :, 0], tri[None, :, 1], tri[None, :, 2])
        return np.linalg.norm(q - pts[:, None, :], axis=2).min(axis=1)
