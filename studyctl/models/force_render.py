"""Force rendering from a stiffness map and a surface mesh, one 1 kHz tick at a time.

Per tick (seeds 002 and 003): the probe's indentation depth is the exact distance to the nearest
triangle of the undeformed surface; the normal and horizontal forces are interpolated from the
force matrices at the contact point and that depth; the normal force acts along the contact normal,
the horizontal force along the probe's motion projected on the table plane; no normal force while the
indentation depth decreases (seed 003 §2.5); every force is clamped at the device maximum (3.3 N, a
PHANToM Omni).

Table edges and depths outside the table, explicitly (never extrapolated)
-------------------------------------------------------------------------
* Outside the mapped (x, y) area: ``outside="zero"`` (default) renders no force — the documented safe
  force; ``outside="clamp"`` holds the value at the nearest edge of the map instead.
* Depth below the shallowest matrix ``d₀``: the force ramps linearly from 0 N at 0 mm to its value at
  ``d₀`` (no contact force at zero indentation).
* Depth beyond the deepest matrix: the deepest matrix's force is held (then saturated at the maximum).
* Inside the grid the cell index is clamped to ``n − 2`` and the fraction to [0, 1], so the last node is
  reached exactly; cubic stencils at the edges use Keys' ghost nodes, which only complete the stencils
  of queries inside the map.

Interpolation variants (``interpolation=``), all on plain Python floats precomputed from the map:
``nearest`` (nearest node in x, y and depth), ``linear`` (trilinear, as the papers state),
``cubic`` (Keys cubic convolution, a = −0.5, with Keys' ghost-node boundary rule, in x and y; 4-point
Lagrange in depth),
``powerlaw`` (bilinear in x and y; between depth nodes ``f ∝ d^α`` with α fitted to the two nodes, exact
for Hertz-like ``d^1.5`` growth; linear where a node force is ≤ 0). ``subsample=k`` keeps every k-th node in
x and y (the cheaper tables of ``studyctl bench render``).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.models.stiffness_map import StiffnessMap
from studyctl.models.surface_mesh import SurfaceMesh

INTERPOLATIONS = ("nearest", "linear", "cubic", "powerlaw")
DEFAULT_INTERPOLATION = "linear"

Lookup = Callable[[float, float, float], tuple[float, float]]


@dataclass(frozen=True)
class RenderParams:
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

    @classmethod
    def from_mapping(cls, params: dict[str, Any], where: str = "render parameters") -> RenderParams:
        """Build from protocol parameters, ignoring keys that are not render parameters."""
        names = set(cls.__dataclass_fields__)
        out = cls(**{k: v for k, v in params.items() if k in names})
        out.validate(where)
        return out

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


# ----------------------------------------------------------------------------------------- look-ups


def _keys_weights(t: float) -> tuple[float, float, float, float]:
    """Keys cubic-convolution weights (a = −0.5) for offsets −1, 0, 1, 2 at fraction t ∈ [0, 1]."""
    t2 = t * t
    t3 = t2 * t
    return (
        -0.5 * t3 + t2 - 0.5 * t,
        1.5 * t3 - 2.5 * t2 + 1.0,
        -1.5 * t3 + 2.0 * t2 + 0.5 * t,
        0.5 * t3 - 0.5 * t2,
    )


def make_lookup(smap: StiffnessMap, interpolation: str = DEFAULT_INTERPOLATION, outside: str = "zero") -> Lookup:
    """A function ``(x_mm, y_mm, depth_mm) -> (normal_n, horizontal_n)`` in the map's frame.

    Values are raw interpolated table forces (not clamped to ≥ 0 or to a maximum; the renderer does that).
    Zero depth or less gives (0, 0); outside the map see the module docstring.
    """
    if interpolation not in INTERPOLATIONS:
        raise ModelParameterError(f"interpolation {interpolation!r}; allowed: {', '.join(INTERPOLATIONS)}")
    if outside not in ("zero", "clamp"):
        raise ModelParameterError(f"outside {outside!r}; allowed: zero, clamp")
    nd, nx, ny = smap.shape
    fn = [float(v) for v in smap.normal_n.ravel()]
    fh = [float(v) for v in smap.horizontal_or_zero().ravel()]
    depths = [float(v) for v in smap.depths_mm]
    x0, y0 = smap.x0_mm, smap.y0_mm
    idx, idy = 1.0 / smap.dx_mm, 1.0 / smap.dy_mm
    umax, vmax = float(nx - 1), float(ny - 1)
    d0, dlast = depths[0], depths[-1]
    sxy = nx * ny
    clamp = outside == "clamp"

    def xy(x: float, y: float) -> tuple[float, float] | None:
        u = (x - x0) * idx
        v = (y - y0) * idy
        if u < 0.0 or v < 0.0 or u > umax or v > vmax:
            if not clamp:
                return None
            u = min(max(u, 0.0), umax)
            v = min(max(v, 0.0), vmax)
        return u, v

    def depth_bracket(d: float) -> tuple[int, float, float]:
        """(k, fraction between depth k and k+1, ramp scale below the first depth)."""
        if d <= d0:
            return 0, 0.0, d / d0
        if d >= dlast:
            return (nd - 2, 1.0, 1.0) if nd > 1 else (0, 0.0, 1.0)
        k = bisect.bisect_right(depths, d) - 1
        return k, (d - depths[k]) / (depths[k + 1] - depths[k]), 1.0

    if interpolation == "nearest":

        def lookup(x: float, y: float, d: float) -> tuple[float, float]:
            if d <= 0.0:
                return 0.0, 0.0
            uv = xy(x, y)
            if uv is None:
                return 0.0, 0.0
            i = int(uv[0] + 0.5)
            j = int(uv[1] + 0.5)
            k, t, ramp = depth_bracket(d)
            if t >= 0.5 and nd > 1:
                k += 1
            b = k * sxy + i * ny + j
            return fn[b] * ramp, fh[b] * ramp

        return lookup

    if interpolation in ("linear", "powerlaw"):
        power = interpolation == "powerlaw"

        nx2, ny2 = nx - 2, ny - 2

        def lookup(x: float, y: float, d: float) -> tuple[float, float]:
            if d <= 0.0:
                return 0.0, 0.0
            # xy() and depth_bracket() inline: this runs every tick in contact
            u = (x - x0) * idx
            v = (y - y0) * idy
            if u < 0.0 or v < 0.0 or u > umax or v > vmax:
                if not clamp:
                    return 0.0, 0.0
                u = min(max(u, 0.0), umax)
                v = min(max(v, 0.0), vmax)
            i = int(u)
            if i > nx2:
                i = nx2
            j = int(v)
            if j > ny2:
                j = ny2
            tu = u - i
            tv = v - j
            w00 = (1.0 - tu) * (1.0 - tv)
            w10 = tu * (1.0 - tv)
            w01 = (1.0 - tu) * tv
            w11 = tu * tv
            if d <= d0:
                k, t, ramp = 0, 0.0, d / d0
            elif d >= dlast:
                k, t, ramp = (nd - 2, 1.0, 1.0) if nd > 1 else (0, 0.0, 1.0)
            else:
                k = bisect.bisect_right(depths, d) - 1
                t, ramp = (d - depths[k]) / (depths[k + 1] - depths[k]), 1.0
            b = k * sxy + i * ny + j
            n_a = fn[b] * w00 + fn[b + ny] * w10 + fn[b + 1] * w01 + fn[b + ny + 1] * w11
            h_a = fh[b] * w00 + fh[b + ny] * w10 + fh[b + 1] * w01 + fh[b + ny + 1] * w11
            if t == 0.0 or nd == 1:
                return n_a * ramp, h_a * ramp
            b += sxy
            n_b = fn[b] * w00 + fn[b + ny] * w10 + fn[b + 1] * w01 + fn[b + ny + 1] * w11
            h_b = fh[b] * w00 + fh[b + ny] * w10 + fh[b + 1] * w01 + fh[b + ny + 1] * w11
            if power and n_a > 0.0 and n_b > 0.0:
                # f = f_a (d/d_a)^α, α = ln(f_b/f_a)/ln(d_b/d_a): the exponent below is ln(d/d_a)/ln(d_b/d_a).
                da, db = depths[k], depths[k + 1]
                dc = da + t * (db - da)  # the depth clamped to the table's range
                e = math.log(dc / da) / math.log(db / da)
                n = n_a * (n_b / n_a) ** e
                h = h_a * (h_b / h_a) ** e if (h_a > 0.0 and h_b > 0.0) else h_a + (h_b - h_a) * t
                return n, h
            return n_a + (n_b - n_a) * t, h_a + (h_b - h_a) * t

        return lookup

    # cubic: Keys in x and y, 4-point Lagrange in depth.
    def lagrange_stencil(d: float) -> tuple[list[int], list[float], float]:
        if d <= d0:
            return [0], [1.0], d / d0
        if d >= dlast:
            return [nd - 1], [1.0], 1.0
        k = bisect.bisect_right(depths, d) - 1
        lo = max(0, min(k - 1, nd - 4))
        ks = list(range(lo, min(lo + 4, nd)))
        ws = []
        for a in ks:
            w = 1.0
            for b in ks:
                if b != a:
                    w *= (d - depths[b]) / (depths[a] - depths[b])
            ws.append(w)
        return ks, ws, 1.0

    # Keys' boundary condition: one ghost node beyond each edge, f₋₁ = 3f₀ − 3f₁ + f₂, so the stencil stays
    # third-order accurate (exact on quadratics) up to the edge. It only completes stencils of queries
    # inside the map; queries outside were clamped or zeroed above.
    pnx, pny = nx + 2, ny + 2
    psxy = pnx * pny
    fn_pad: list[float] = []
    fh_pad: list[float] = []
    for stack, out in ((smap.normal_n, fn_pad), (smap.horizontal_or_zero(), fh_pad)):
        padded = np.empty((nd, pnx, pny))
        padded[:, 1:-1, 1:-1] = stack
        if nx >= 3:
            padded[:, 0, 1:-1] = 3 * stack[:, 0] - 3 * stack[:, 1] + stack[:, 2]
            padded[:, -1, 1:-1] = 3 * stack[:, -1] - 3 * stack[:, -2] + stack[:, -3]
        else:
            padded[:, 0, 1:-1] = 2 * stack[:, 0] - stack[:, 1]
            padded[:, -1, 1:-1] = 2 * stack[:, -1] - stack[:, -2]
        if ny >= 3:
            padded[:, :, 0] = 3 * padded[:, :, 1] - 3 * padded[:, :, 2] + padded[:, :, 3]
            padded[:, :, -1] = 3 * padded[:, :, -2] - 3 * padded[:, :, -3] + padded[:, :, -4]
        else:
            padded[:, :, 0] = 2 * padded[:, :, 1] - padded[:, :, 2]
            padded[:, :, -1] = 2 * padded[:, :, -2] - padded[:, :, -3]
        out.extend(float(v) for v in padded.ravel())

    def lookup(x: float, y: float, d: float) -> tuple[float, float]:
        if d <= 0.0:
            return 0.0, 0.0
        uv = xy(x, y)
        if uv is None:
            return 0.0, 0.0
        u, v = uv
        i = int(u)
        if i > nx - 2:
            i = nx - 2
        j = int(v)
        if j > ny - 2:
            j = ny - 2
        wu = _keys_weights(u - i)
        wv = _keys_weights(v - j)
        ii = [(i + o) * pny for o in (0, 1, 2, 3)]  # padded indices of nodes i−1 … i+2
        jj = [j, j + 1, j + 2, j + 3]
        ks, ws, ramp = lagrange_stencil(d)
        n_sum = 0.0
        h_sum = 0.0
        pn, ph = fn_pad, fh_pad
        for kk, wk in zip(ks, ws, strict=True):
            base = kk * psxy
            for a in range(4):
                row = base + ii[a]
                wa = wk * wu[a]
                n_row = (
                    pn[row + jj[0]] * wv[0]
                    + pn[row + jj[1]] * wv[1]
                    + pn[row + jj[2]] * wv[2]
                    + pn[row + jj[3]] * wv[3]
                )
                h_row = (
                    ph[row + jj[0]] * wv[0]
                    + ph[row + jj[1]] * wv[1]
                    + ph[row + jj[2]] * wv[2]
                    + ph[row + jj[3]] * wv[3]
                )
                n_sum += wa * n_row
                h_sum += wa * h_row
        return n_sum * ramp, h_sum * ramp

    return lookup


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
