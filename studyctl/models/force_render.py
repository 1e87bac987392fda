"""Force rendering from a stiffness map and a surface mesh, one 1 kHz tick at a time.

Per tick (seeds 002 and 003): the probe's indentation depth is the exact distance to the nearest
triangle of the undeformed surface; the normal and horizontal forces are interpolated from the
force matrices at the contact point and that depth; the normal force acts along the contact normal,
the horizontal force along the probe's motion projected on the table plane; no normal force while the
indentation depth decreases (seed 003 §2.5); every force is clamped at the device maximum (3.3 N, a
PHANToM Omni).

The table look-ups (edges, depths outside the table, interpolation variants) are in
:mod:`studyctl.models.force_lookup`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.models.force_lookup import DEFAULT_INTERPOLATION, INTERPOLATIONS, make_lookup
from studyctl.models.param_block import ParamBlock
from studyctl.models.stiffness_map import StiffnessMap
from studyctl.models.surface_mesh import SurfaceMesh


@dataclass(frozen=True)
class RenderParams(ParamBlock):
    """Parameters of :class:`ForceRenderer` (protocol names in brackets are the same).

    max_force_n : clamp of each force and of the total (3.3 N, PHANToM Omni).
    interpolation : one of :data:`INTERPOLATIONS`.
    subsample : keep every k-th map node in x and y (1 = full table).
    outside : "zero" (no force outside the mapped area) or "clamp" (hold the edge value).
    release_on_retract : no normal force while the indentation depth decreases (seed 003).
    retract_deadband_mm : depth must fall this far below its running reference before the tick counts as
        retracting (hysteresis against position noise); rising above the reference ends retraction.
    horizontal : "oppose" (the reaction resists the motion), "along" (seed 003's eq. 5 read literally) or
        "off" (seed 002 fed back the normal force only).
    min_motion_mm : the horizontal direction is re-estimated once the probe has moved this far in the
        table plane since the last estimate (noise-robust); until the first estimate there is none.
    """

    max_force_n: float = 3.3
    interpolation: str = DEFAULT_INTERPOLATION
    subsample: int = 1
    outside: str = "zero"
    release_on_retract: bool = True
    retract_deadband_mm: float = 0.02
    horizontal: str = "oppose"
    min_motion_mm: float = 0.05

    def validate(self, where: str = "render parameters") -> None:
        if not (isinstance(self.max_force_n, int | float) and math.isfinite(self.max_force_n) and self.max_force_n > 0):
            raise ModelParameterError(f"{where}: max_force_n is {self.max_force_n!r}; it must be a positive force in N")
        if self.interpolation not in INTERPOLATIONS:
            raise ModelParameterError(
                f"{where}: interpolation is {self.interpolation!r}; allowed: {', '.join(INTERPOLATIONS)}"
            )
        if not isinstance(self.subsample, int) or isinstance(self.subsample, bool) or self.subsample < 1:
            raise ModelParameterError(f"{where}: subsample is {self.subsample!r}; it must be an integer ≥ 1")
        if self.outside not in ("zero", "clamp"):
            raise ModelParameterError(f"{where}: outside is {self.outside!r}; allowed: zero, clamp")
        if self.horizontal not in ("oppose", "along", "off"):
            raise ModelParameterError(f"{where}: horizontal is {self.horizontal!r}; allowed: oppose, along, off")
        for name in ("retract_deadband_mm", "min_motion_mm"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ModelParameterError(f"{where}: {name} is {value!r}; it must be ≥ 0 mm")


# ------------------------------------------------------------------------------------------ renderer


@dataclass(frozen=True)
class Placement:
    """Rigid placement of the tissue in the device frame: rotation about z by ``rotation_deg`` around the
    tissue-frame point ``center_mm``, then a shift by ``offset_mm`` (seed 003 randomises the block's
    orientation per test)."""

    rotation_deg: float = 0.0
    center_mm: tuple[float, float] = (0.0, 0.0)
    offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_world(self, x: float, y: float, z: float = 0.0) -> tuple[float, float, float]:
        c, s = math.cos(math.radians(self.rotation_deg)), math.sin(math.radians(self.rotation_deg))
        dx, dy = x - self.center_mm[0], y - self.center_mm[1]
        return (
            self.center_mm[0] + c * dx - s * dy + self.offset_mm[0],
            self.center_mm[1] + s * dx + c * dy + self.offset_mm[1],
            z + self.offset_mm[2],
        )

    def to_local(self, x: float, y: float, z: float = 0.0) -> tuple[float, float, float]:
        c, s = math.cos(math.radians(self.rotation_deg)), math.sin(math.radians(self.rotation_deg))
        dx = x - self.offset_mm[0] - self.center_mm[0]
        dy = y - self.offset_mm[1] - self.center_mm[1]
        return (self.center_mm[0] + c * dx + s * dy, self.center_mm[1] - s * dx + c * dy, z - self.offset_mm[2])


@dataclass(frozen=True)
class RenderedForce:
    """One tick's result: device-frame force (N), the two magnitudes, depth (mm) and state flags."""

    fx_n: float
    fy_n: float
    fz_n: float
    normal_n: float
    horizontal_n: float
    depth_mm: float
    contact: bool
    retracting: bool


class ForceRenderer:
    """Stateful per-tick force rendering (the state: depth reference for the retraction rule and the
    motion anchor for the horizontal direction). Call :meth:`reset` before each trial.

    Parameters
    ----------
    smap : the stiffness map (tissue frame)
    mesh : the undeformed surface (tissue frame)
    params : :class:`RenderParams`
    placement : where the tissue sits in the device frame
    """

    def __init__(
        self,
        smap: StiffnessMap,
        mesh: SurfaceMesh,
        params: RenderParams | None = None,
        placement: Placement | None = None,
    ) -> None:
        self.params = params or RenderParams()
        self.params.validate()
        self.map = smap if self.params.subsample == 1 else smap.subsample(self.params.subsample)
        self.mesh = mesh
        self.placement = placement or Placement()
        self._lookup = make_lookup(self.map, self.params.interpolation, self.params.outside)
        rad = math.radians(self.placement.rotation_deg)
        self._c, self._s = math.cos(rad), math.sin(rad)
        self._cx, self._cy = (float(v) for v in self.placement.center_mm)
        self._ox, self._oy, self._oz = (float(v) for v in self.placement.offset_mm)
        self._fmax = float(self.params.max_force_n)
        self._sign = {"oppose": -1.0, "along": 1.0, "off": 0.0}[self.params.horizontal]
        # Parameters read every tick (params is frozen): plain attributes, the squared motion threshold once.
        lim = self.params.min_motion_mm
        self._min_motion2 = lim * lim
        self._deadband = self.params.retract_deadband_mm
        self._release = self.params.release_on_retract
        self._indentation = self.mesh.indentation
        self.reset()

    def reset(self) -> None:
        self._depth_ref = 0.0
        self._retracting = False
        self._anchor: tuple[float, float] | None = None
        self._dir = (0.0, 0.0)
        # The last tick's contact point (tissue frame) and clamped table forces before the retraction rule:
        # what a pseudo-haptic cursor and a deformation view need, without a second mesh query.
        self.last_contact_xy = (0.0, 0.0)
        self.last_table_n = 0.0
        self.last_table_h = 0.0

    def render(self, x: float, y: float, z: float) -> tuple[float, float, float, float, float, float, bool, bool]:
        """One tick for a probe at device-frame (x, y, z) mm.

        Returns ``(fx, fy, fz, normal, horizontal, depth, contact, retracting)`` in the device frame
        (plain floats; :meth:`render_force` wraps the same in a :class:`RenderedForce`).
        """
        c, s = self._c, self._s
        dx = x - self._ox - self._cx
        dy = y - self._oy - self._cy
        lx = self._cx + c * dx + s * dy
        ly = self._cy - s * dx + c * dy
        lz = z - self._oz
        # The motion direction is tracked whether or not the probe touches, so it is ready on contact.
        anchor = self._anchor
        if anchor is None:
            self._anchor = (lx, ly)
        else:
            mx, my = lx - anchor[0], ly - anchor[1]
            m2 = mx * mx + my * my
            if m2 > self._min_motion2 and m2 > 0.0:
                inv = 1.0 / math.sqrt(m2)
                self._dir = (mx * inv, my * inv)
                self._anchor = (lx, ly)
        hit = self._indentation(lx, ly, lz)
        if hit is None:
            self._depth_ref = 0.0
            self._retracting = False
            self.last_table_n = self.last_table_h = 0.0
            return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, False)
        depth, qx, qy, _qz, nx, ny, nz = hit
        fn, fh = self._lookup(qx, qy, depth)
        fmax = self._fmax
        fn = 0.0 if fn < 0.0 else (fmax if fn > fmax else fn)
        fh = 0.0 if fh < 0.0 else (fmax if fh > fmax else fh)
        self.last_contact_xy = (qx, qy)
        self.last_table_n = fn
        self.last_table_h = fh
        if depth > self._depth_ref:
            self._depth_ref = depth
            self._retracting = False
        elif depth < self._depth_ref - self._deadband:
            self._depth_ref = depth
            self._retracting = True
        retracting = self._retracting
        if retracting and self._release:
            fn = 0.0
        hx, hy = self._dir
        sh = self._sign * fh
        lfx = fn * nx + sh * hx
        lfy = fn * ny + sh * hy
        lfz = fn * nz
        mag2 = lfx * lfx + lfy * lfy + lfz * lfz
        if mag2 > fmax * fmax:
            scale = fmax / math.sqrt(mag2)
            lfx, lfy, lfz = lfx * scale, lfy * scale, lfz * scale
        return (c * lfx - s * lfy, s * lfx + c * lfy, lfz, fn, fh, depth, True, retracting)

    def render_force(self, x: float, y: float, z: float) -> RenderedForce:
        return RenderedForce(*self.render(x, y, z))

    def lookup_local(self, x: float, y: float, depth: float) -> tuple[float, float]:
        """Clamped (≥ 0, ≤ max) table forces at a tissue-frame surface point and depth (no state)."""
        fn, fh = self._lookup(x, y, depth)
        fmax = self._fmax
        return min(max(fn, 0.0), fmax), min(max(fh, 0.0), fmax)


def reference_forces(smap: StiffnessMap, points: np.ndarray) -> np.ndarray:
    """Normal force at (x, y, depth) rows from the full table by SciPy splines: the independent reference
    of the render benchmark.

    Cubic splines in x and y (``RegularGridInterpolator(method="cubic")`` on each depth's matrix), then an
    interpolating spline in depth of degree ``min(3, n_depths − 1)`` (``make_interp_spline``). Points must
    lie inside the grid and the depth range.
    """
    from scipy.interpolate import RegularGridInterpolator, make_interp_spline

    pts = np.asarray(points, dtype=float)
    per_depth = np.empty((smap.shape[0], pts.shape[0]))
    method = "cubic" if min(smap.shape[1:]) >= 4 else "linear"
    for k in range(smap.shape[0]):
        rgi = RegularGridInterpolator((smap.xs_mm, smap.ys_mm), smap.normal_n[k], method=method)
        per_depth[k] = rgi(pts[:, :2])
    if smap.shape[0] == 1:
        return per_depth[0]
    spline = make_interp_spline(smap.depths_mm, per_depth, k=min(3, smap.shape[0] - 1), axis=0)
    out = np.empty(pts.shape[0])
    for start in range(0, pts.shape[0], 256):  # each point has its own depth: evaluate in chunks, keep the diagonal
        sl = slice(start, start + 256)
        out[sl] = np.diagonal(spline(pts[sl, 2])[:, sl])
    return out
