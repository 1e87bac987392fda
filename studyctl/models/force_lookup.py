"""Table look-ups of a stiffness map: ``(x_mm, y_mm, depth_mm) -> (normal_n, horizontal_n)`` on plain floats.

The renderer (:mod:`studyctl.models.force_render`) calls one every 1 kHz tick in contact, so each variant is a
closure over lists of floats precomputed from the map, with the hottest path (linear) written inline.

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

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.models.stiffness_map import StiffnessMap

INTERPOLATIONS = ("nearest", "linear", "cubic", "powerlaw")
DEFAULT_INTERPOLATION = "linear"

Lookup = Callable[[float, float, float], tuple[float, float]]


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

    def pressed_uv(x: float, y: float, d: float) -> tuple[float, float] | None:
        """Map coordinates (u, v) of a press ``d`` mm deep at (x, y); None where it gives no force: at or above the
        surface, or off the map (unless clamped)."""
        if d <= 0.0:
            return None
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
            uv = pressed_uv(x, y, d)
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
            # pressed_uv() and depth_bracket() inline: this runs every tick in contact
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
        uv = pressed_uv(x, y, d)
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


__all__ = ["DEFAULT_INTERPOLATION", "INTERPOLATIONS", "Lookup", "make_lookup"]
