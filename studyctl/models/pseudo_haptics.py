"""Pseudo-haptic feedback (seed 003 §2.4, Table 1) and its geometric deformation view (§2.3).

Cursor/input ratios
-------------------
The cursor moves by ``R · ΔD`` for an input (stylus) increment ``ΔD``; ``R`` never multiplies the input's
absolute position, so a change of force changes the cursor's *speed*, never its position (no jumps):

* normal (z) increments: ``R_n = R₀ / (f_n + 1)`` while ``Δf_n = f_n − f_nl > 0``, else ``R₀``;
* horizontal (x, y) increments: ``R_h = R₀ / (f_h + 1)`` while ``Δf_n > 0`` (the tissue under the cursor is
  getting stiffer), else ``R₀``.

``f_n``, ``f_h`` are the table forces (N, clamped ≥ 0) at the current cursor and ``f_nl`` the normal force at
the previous cursor position. The paper is not consistent here: equation (3) and the text ("R_h is the modified
horizontal cursor/user input ratio") define ``R_h`` for horizontal motion, while Table 1 — which the text calls
the summary of the rules — prints ``d_m(x, y) = R_n · D(x, y)``. ``lateral_ratio`` chooses: ``horizontal``
(equation 3, the default) or ``normal`` (Table 1). It matters: the rolling-indentation tables' horizontal force
is a rolling resistance (on seed 003's synthetic block 0.04 N over the tissue, 0.06 N over a nodule at 5 mm), so
by equation 3 a cursor slid sideways at depth slows by at most ~5 % anywhere, below the 6 % pseudo-haptic JND
(Lécuyer et al. 2000); by Table 1 it slows as a press does, by ``f_n + 1`` (~1.9 over the tissue, ~2.2 over
nodule A at 5 mm): the sideways slowing towards a hard area that §2.4 describes.

The ratios make the cursor lag the hand, and Table 1 alone never gives the lag back. Out of contact the
cursor therefore drifts back towards the hand's ``R₀``-mapped position at most ``resync_mm_per_s``
(a documented choice; 0 disables it) — a bounded speed, so the cursor still never jumps.

Deformation view
----------------
:class:`DeformationView` displaces the nodes of a display grid around the indenter: inside the contact
the surface takes the indenter's shape, outside it sags as Hertz's elastic half-space does around a sphere,
tapered to zero at ``taper_radius`` (chosen: the paper gives the construction and the demarcation depths,
not the fall-off functions; see :func:`deformation_profile_array`). The
geometric contact radius ``a = √(2 r d − d²)`` (``d < r``) reaches ``r/2`` at ``d = (2 − √3) r/2``, the
first of the paper's demarcation depths (:func:`deformation_range`); the others are ``r`` (the
equator reaches the surface) and ``2r`` (the sphere is fully submerged).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.models.param_block import ParamBlock

LATERAL_RATIOS = ("horizontal", "normal")


@dataclass(frozen=True)
class PseudoHapticParams(ParamBlock):
    """r0 : default cursor/input ratio R₀ (> 0).
    resync_mm_per_s : out-of-contact speed at which the cursor returns towards the hand's R₀-mapped position.
    delta_threshold_n : Δf_n must exceed this for the reduced ratios to apply (0 = the paper's rule).
    lateral_ratio : the force that slows horizontal increments: ``horizontal`` (f_h, equation 3) or ``normal``
        (f_n, Table 1).
    """

    r0: float = 1.0
    resync_mm_per_s: float = 10.0
    delta_threshold_n: float = 0.0
    lateral_ratio: str = "horizontal"

    def validate(self, where: str = "pseudo-haptic parameters") -> None:
        if not (isinstance(self.r0, int | float) and math.isfinite(self.r0) and self.r0 > 0):
            raise ModelParameterError(f"{where}: r0 is {self.r0!r}; the default cursor/input ratio must be > 0")
        for name in ("resync_mm_per_s", "delta_threshold_n"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ModelParameterError(f"{where}: {name} is {value!r}; it must be ≥ 0")
        if self.lateral_ratio not in LATERAL_RATIOS:
            raise ModelParameterError(
                f"{where}: lateral_ratio is {self.lateral_ratio!r}; allowed: {', '.join(LATERAL_RATIOS)} "
                "(horizontal: equation 3, R_h from the horizontal force; normal: Table 1, R_n for x and y too)"
            )


def ratio(r0: float, force_n: float) -> float:
    """``R = R₀ / (f + 1)`` with the force clamped at ≥ 0 (seed 003 equations 2 and 3)."""
    return r0 / ((force_n if force_n > 0.0 else 0.0) + 1.0)


class PseudoHapticCursor:
    """The cursor of seed 003's pseudo-haptic feedback, updated from input increments.

    Call :meth:`reset` with the first input and cursor positions, then :meth:`step` every tick with the new
    input position and the table forces at the *current* cursor (before the move). Positions are mm in one
    frame (the device frame after workspace mapping).
    """

    def __init__(self, params: PseudoHapticParams | None = None) -> None:
        self.params = params or PseudoHapticParams()
        self.params.validate()
        self._lateral_normal = self.params.lateral_ratio == "normal"
        self.reset((0.0, 0.0, 0.0))

    def reset(self, input_mm: tuple[float, float, float], cursor_mm: tuple[float, float, float] | None = None) -> None:
        r0 = self.params.r0
        self._input = tuple(float(v) for v in input_mm)
        self._cursor = tuple(float(v) for v in (cursor_mm if cursor_mm is not None else input_mm))
        # The R₀-mapped "home" of the cursor: cursor_home = origin + R₀ (input − input0).
        self._origin = tuple(c - r0 * i for c, i in zip(self._cursor, self._input, strict=True))
        self._f_prev: float | None = None
        self.last_ratio_n = r0
        self.last_ratio_h = r0

    @property
    def cursor(self) -> tuple[float, float, float]:
        return self._cursor  # type: ignore[return-value]

    def step(
        self, input_mm: tuple[float, float, float], f_n: float, f_h: float, in_contact: bool, dt: float
    ) -> tuple[float, float, float]:
        """Move the cursor for this tick's input increment; returns the new cursor position."""
        p = self.params
        r0 = p.r0
        ix, iy, iz = input_mm
        px, py, pz = self._input
        dx, dy, dz = ix - px, iy - py, iz - pz
        self._input = (ix, iy, iz)
        f_prev = self._f_prev
        stiffer = f_prev is not None and (f_n - f_prev) > p.delta_threshold_n
        self._f_prev = f_n if in_contact else 0.0
        rn = ratio(r0, f_n) if stiffer else r0
        rh = (rn if self._lateral_normal else ratio(r0, f_h)) if stiffer else r0
        self.last_ratio_n, self.last_ratio_h = rn, rh
        cx, cy, cz = self._cursor
        cx += rh * dx
        cy += rh * dy
        cz += rn * dz
        if not in_contact and p.resync_mm_per_s > 0.0:
            ox, oy, oz = self._origin
            hx, hy, hz = ox + r0 * ix - cx, oy + r0 * iy - cy, oz + r0 * iz - cz
            gap = math.sqrt(hx * hx + hy * hy + hz * hz)
            step = p.resync_mm_per_s * dt
            if gap > 0.0:
                k = 1.0 if gap <= step else step / gap
                cx, cy, cz = cx + k * hx, cy + k * hy, cz + k * hz
        self._cursor = (cx, cy, cz)
        return self._cursor


# ----------------------------------------------------------------------------------- deformation view


def contact_radius(depth_mm: float, r_mm: float) -> float:
    """Radius of the circle where a sphere of radius ``r`` pressed ``depth`` deep meets the undeformed plane."""
    if depth_mm <= 0.0:
        return 0.0
    if depth_mm >= r_mm:
        return r_mm
    return math.sqrt(2.0 * r_mm * depth_mm - depth_mm * depth_mm)


def deformation_range(depth_mm: float, r_mm: float) -> str:
    """Seed 003 Fig. 3(c)'s four ranges: 'a' below (2 − √3) r/2, 'b' below r, 'c' below 2r, 'd' beyond."""
    if depth_mm < (2.0 - math.sqrt(3.0)) * r_mm / 2.0:
        return "a"
    if depth_mm < r_mm:
        return "b"
    if depth_mm < 2.0 * r_mm:
        return "c"
    return "d"


def deformation_profile(rho_mm: float, depth_mm: float, r_mm: float, taper_radius_mm: float) -> float:
    """Downward displacement (mm, ≥ 0) of the surface at distance ``rho`` from the indentation centre."""
    return float(deformation_profile_array(np.array([rho_mm], dtype=float), depth_mm, r_mm, taper_radius_mm)[0])


def deformation_profile_array(rho_mm: np.ndarray, depth_mm: float, r_mm: float, taper_radius_mm: float) -> np.ndarray:
    """Surface displacement (mm, ≥ 0) at distances ``rho`` from the indentation centre, vectorised.

    Hertz's surface displacement of an elastic half-space under a sphere of radius ``r`` (Johnson, *Contact
    Mechanics*, 1985, §3.4) for ``δ = min(depth, r)``: ``δ − ρ²/2r`` inside the contact radius ``a = √(r δ)``
    (the indenter's shape), ``((2a² − ρ²) asin(a/ρ) + a √(ρ² − a²))/(π r)`` outside (continuous at ``a``, where
    both are ``δ/2``); deeper than ``r`` the whole patch is pushed down by the remaining ``depth − r``. The
    result is multiplied by ``(1 − (ρ/ρ_t)²)²`` so that nothing moves beyond the taper radius ``ρ_t``; it is
    continuous, falls monotonically with ``ρ`` and equals ``depth`` at the centre.
    """
    rho = np.abs(np.asarray(rho_mm, dtype=float))
    if depth_mm <= 0.0:
        return np.zeros_like(rho)
    delta = min(depth_mm, r_mm)
    a = math.sqrt(r_mm * delta)
    with np.errstate(divide="ignore", invalid="ignore"):
        outside = (
            (2 * a * a - rho * rho) * np.arcsin(np.clip(a / rho, 0.0, 1.0))
            + a * np.sqrt(np.maximum(rho * rho - a * a, 0.0))
        ) / (math.pi * r_mm)
    hertz = np.where(rho <= a, delta - rho * rho / (2.0 * r_mm), outside)
    taper = np.clip(1.0 - (rho / taper_radius_mm) ** 2, 0.0, 1.0) ** 2
    return np.maximum((depth_mm - delta) + hertz, 0.0) * taper


def neighbour_depths(depth_a_mm: float, r_mm: float, taper_radius_mm: float | None = None) -> tuple[float, ...]:
    """``(d_A, d_B, …, d_G)``: displacements at 0, r/2, r, …, 3r from the centre (seed 003 §2.3)."""
    taper = taper_radius_mm if taper_radius_mm is not None else 4.0 * r_mm
    return tuple(deformation_profile(k * r_mm / 2.0, depth_a_mm, r_mm, taper) for k in range(7))


@dataclass(frozen=True)
class DeformationFrame:
    """Displaced display nodes for one cursor state: ``nodes`` are ``(i, j, dz_mm)`` with dz < 0 (down)."""

    center_mm: tuple[float, float]
    depth_mm: float
    contact_radius_mm: float
    range: str
    nodes: tuple[tuple[int, int, float], ...]

    def to_dict(self) -> dict[str, Any]:
        return {
            "center_mm": list(self.center_mm),
            "depth_mm": self.depth_mm,
            "contact_radius_mm": self.contact_radius_mm,
            "range": self.range,
            "nodes": [list(n) for n in self.nodes],
        }


class PendingDeformation:
    """A deformation frame that is computed only when something draws it (:meth:`compute`, cached).

    The control loop hands one of these to the view every tick at almost no cost; a display drawing at
    60 Hz computes the few frames it shows, so the deformation mesh is updated only when someone looks.
    """

    __slots__ = ("_view", "center_mm", "depth_mm", "_frame")

    def __init__(self, view: DeformationView, center_mm: tuple[float, float], depth_mm: float) -> None:
        self._view = view
        self.center_mm = center_mm
        self.depth_mm = depth_mm
        self._frame: DeformationFrame | None = None

    def compute(self) -> DeformationFrame:
        if self._frame is None:
            self._frame = self._view.frame(self.center_mm[0], self.center_mm[1], self.depth_mm)
        return self._frame


class DeformationView:
    """The geometric deformable tissue display of seed 003 §2.3 over a regular display grid.

    Parameters
    ----------
    xs_mm, ys_mm : display-grid node coordinates (tissue frame)
    indenter_radius_mm : ``r`` of the spherical indenter avatar
    taper_radius_mm : beyond this distance from the centre nothing moves (default 4 r)
    """

    def __init__(
        self, xs_mm: Any, ys_mm: Any, indenter_radius_mm: float = 5.0, taper_radius_mm: float | None = None
    ) -> None:
        if not (
            isinstance(indenter_radius_mm, int | float) and math.isfinite(indenter_radius_mm) and indenter_radius_mm > 0
        ):
            raise ModelParameterError(f"deformation view: indenter_radius_mm is {indenter_radius_mm!r}; must be > 0")
        self.xs = np.asarray(xs_mm, dtype=float).reshape(-1)
        self.ys = np.asarray(ys_mm, dtype=float).reshape(-1)
        if self.xs.size < 2 or self.ys.size < 2 or np.any(np.diff(self.xs) <= 0) or np.any(np.diff(self.ys) <= 0):
            raise ModelParameterError("deformation view: the display grid needs ≥ 2 × 2 strictly increasing nodes")
        self.r = float(indenter_radius_mm)
        self.taper = float(taper_radius_mm) if taper_radius_mm is not None else 4.0 * self.r
        if self.taper <= self.r:
            raise ModelParameterError(
                f"deformation view: taper_radius_mm {self.taper} must exceed the indenter radius {self.r}"
            )

    def pending(self, center_x_mm: float, center_y_mm: float, depth_mm: float) -> PendingDeformation:
        """A frame to compute later (what the scene's view hands out every tick)."""
        return PendingDeformation(self, (float(center_x_mm), float(center_y_mm)), max(float(depth_mm), 0.0))

    def frame(self, center_x_mm: float, center_y_mm: float, depth_mm: float) -> DeformationFrame:
        """Displacements of the nodes within the taper radius of the indentation centre."""
        d = max(float(depth_mm), 0.0)
        nodes: tuple[tuple[int, int, float], ...] = ()
        if d > 0.0:
            t = self.taper
            i0, i1 = np.searchsorted(self.xs, [center_x_mm - t, center_x_mm + t], side="left")
            j0, j1 = np.searchsorted(self.ys, [center_y_mm - t, center_y_mm + t], side="left")
            if i1 > i0 and j1 > j0:
                gx, gy = np.meshgrid(self.xs[i0:i1] - center_x_mm, self.ys[j0:j1] - center_y_mm, indexing="ij")
                u = deformation_profile_array(np.hypot(gx, gy), d, self.r, t)
                ii, jj = np.nonzero(u > 1e-6)
                nodes = tuple((int(i + i0), int(j + j0), -float(u[i, j])) for i, j in zip(ii, jj, strict=True))
        return DeformationFrame(
            (float(center_x_mm), float(center_y_mm)),
            d,
            contact_radius(d, self.r),
            deformation_range(d, self.r),
            nodes,
        )
