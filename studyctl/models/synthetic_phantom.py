"""Synthetic stiffness maps for when a lab has no measurements: documented approximations of the
phantoms of seeds 002 and 003.

**These are not measurements.** They stand in for the rolling-indentation matrices so that studies,
tests and benchmarks can run; a study that reports results on real phantoms should load the lab's own
matrices with :func:`studyctl.models.stiffness_map_files.load_stiffness_map`.

Force model (each step is an approximation and says so)
-------------------------------------------------------
1. *Homogeneous tissue*: Hertz contact of a rigid sphere of radius ``R`` on an incompressible half-space
   (ν = 0.5, E* = 4E/3): ``F = 16/9 · E · √R · d^1.5``.
2. *Finite, bonded thickness* ``h`` (the block sits on a rigid table): the bonded-layer correction of
   Dimitriadis et al. (Biophys. J. 82:2798, 2002) for ν = 0.5,
   ``× (1 + 1.133χ + 1.283χ² + 0.769χ³ + 0.0975χ⁴)``, ``χ = √(R d)/h``, using the local thickness.
3. *Stiff nodules*: each nodule carries a fraction ``φ`` of the indenter's strain-energy weight, the
   Boussinesq vertical-stress kernel squared, ``w ∝ Z⁶/(ρ² + Z²)⁵``, normalised over the half-space with
   the point load spread over the contact radius ``c = √(R d)`` (``Z = z + c``). Material under the tip
   is compressed uniformly over the column down to the table (a point at depth ``z`` ends up
   ``z (1 − d/h)`` below the tip). The effective modulus follows Lichtenecker's logarithmic mixing rule,
   ``E_eff = E_t · Π_k (E_k/E_t)^φ_k``.
4. *Horizontal (rolling) force*: a rolling-resistance coefficient times the normal force (both seeds
   lubricated the surface; seed 002 calls the tangential force "very small").
5. *Sensor noise*: Gaussian, standard deviation ``noise_n`` (the Nano17's 0.003 N resolution), drawn
   from the passed generator.

Geometry choices the papers do not state are marked "chosen" in the docstrings below.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
import pandas as pd

from studyctl.errors import ModelParameterError
from studyctl.models.stiffness_map import StiffnessMap


@dataclass(frozen=True)
class Nodule:
    """A spherical hard inclusion; ``top_depth_mm`` is from the surface to the top of the sphere."""

    name: str
    x_mm: float
    y_mm: float
    diameter_mm: float
    top_depth_mm: float
    modulus_kpa: float


@dataclass(frozen=True, eq=False)
class SyntheticPhantom:
    """A generated phantom: its force maps, its surface height grid and its hidden nodules.

    ``surface_heights_mm[i, j]`` is the height above the table at ``(surface_xs_mm[i], surface_ys_mm[j])``.
    ``nodules`` is ground truth: scenes hand it to metrics, never to participants.
    """

    name: str
    stiffness: StiffnessMap
    surface_xs_mm: np.ndarray
    surface_ys_mm: np.ndarray
    surface_heights_mm: np.ndarray
    nodules: tuple[Nodule, ...]
    parameters: dict[str, Any] = field(default_factory=dict)

    @property
    def footprint_mm(self) -> tuple[float, float, float, float]:
        return (
            float(self.surface_xs_mm[0]),
            float(self.surface_xs_mm[-1]),
            float(self.surface_ys_mm[0]),
            float(self.surface_ys_mm[-1]),
        )

    def to_frame(self) -> pd.DataFrame:
        """The nodules: columns name, x_mm, y_mm, diameter_mm, top_depth_mm, modulus_kpa."""
        return pd.DataFrame(
            [(n.name, n.x_mm, n.y_mm, n.diameter_mm, n.top_depth_mm, n.modulus_kpa) for n in self.nodules],
            columns=["name", "x_mm", "y_mm", "diameter_mm", "top_depth_mm", "modulus_kpa"],
        )


def hertz_force_n(modulus_kpa: float | np.ndarray, radius_mm: float, depth_mm: float | np.ndarray) -> np.ndarray:
    """Hertz force (N) of a rigid sphere (radius in mm) pressed ``depth_mm`` into an incompressible half-space."""
    return (16.0 / 9.0) * np.asarray(modulus_kpa) * 1e-3 * math.sqrt(radius_mm) * np.asarray(depth_mm) ** 1.5


def bonded_layer_factor(radius_mm: float, depth_mm: np.ndarray, thickness_mm: np.ndarray) -> np.ndarray:
    """Dimitriadis et al. (2002) bonded-layer correction for ν = 0.5; χ capped at 1 (the fit's range)."""
    chi = np.minimum(np.sqrt(radius_mm * np.asarray(depth_mm)) / np.asarray(thickness_mm), 1.0)
    return 1.0 + 1.133 * chi + 1.283 * chi**2 + 0.769 * chi**3 + 0.0975 * chi**4


def _unit_ball_points(per_axis: int) -> np.ndarray:
    """Cell centres of a cubic lattice inside the unit ball (equal-volume quadrature points)."""
    g = (np.arange(per_axis) + 0.5) / per_axis * 2.0 - 1.0
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    return pts[np.einsum("ij,ij->i", pts, pts) <= 1.0]


# columns per block of nodule_weight: three float64 buffers of 128 × 268 quadrature points, about 0.8 MB
_WEIGHT_ROWS = 128


def nodule_weight(
    probe_x: np.ndarray,
    probe_y: np.ndarray,
    surface_height: np.ndarray,
    depth_mm: float,
    nodule: Nodule,
    nodule_center_z: float,
    radius_mm: float,
    quadrature: int = 8,
) -> np.ndarray:
    """Fraction ``φ`` of the indenter's strain-energy weight that falls inside ``nodule`` (step 3 above).

    ``probe_x``, ``probe_y`` and ``surface_height`` (the local thickness above the table) are 1-D arrays of
    probe positions; ``nodule_center_z`` is the centre's height above the table.
    """
    a = nodule.diameter_mm / 2.0
    q = _unit_ball_points(quadrature) * a
    dv = (4.0 / 3.0) * math.pi * a**3 / len(q)
    qx = (nodule.x_mm + q[:, 0])[None, :]
    qy = (nodule.y_mm + q[:, 1])[None, :]
    qz = (nodule_center_z + q[:, 2])[None, :]
    c = math.sqrt(radius_mm * depth_mm)
    px = np.asarray(probe_x, dtype=float)[:, None]
    py = np.asarray(probe_y, dtype=float)[:, None]
    thickness = np.asarray(surface_height, dtype=float)[:, None]
    squeeze = np.clip(1.0 - depth_mm / thickness, 0.0, 1.0)
    weight = dv * squeeze
    sums = np.empty(len(thickness))
    # (columns × quadrature points) blocks of _WEIGHT_ROWS columns in three reused buffers: each element takes the
    # same operations in the same order as the expressions in the comments, and each column's sum is over its own
    # row, so blocks give the same bits as one array; buffers that stay in cache and are not faulted in afresh for
    # every step make a force-map synthesis (once per process and phantom) three times faster (seed 003's block:
    # 0.65 s CPU → 0.21 s)
    rows = max(min(_WEIGHT_ROWS, len(thickness)), 1)
    big_z, rho2, w = (np.empty((rows, len(q))) for _ in range(3))
    mask = np.empty((rows, len(q)), dtype=bool)
    for lo in range(0, len(thickness), rows):
        hi = min(lo + rows, len(thickness))
        z, r2, ww, m = big_z[: hi - lo], rho2[: hi - lo], w[: hi - lo], mask[: hi - lo]
        np.subtract(thickness[lo:hi], qz, out=z)  # depth of each quadrature point below the surface at the column
        np.less_equal(z, 0.0, out=m)  # points above the surface
        z *= squeeze[lo:hi]  # below the tip after the column compression: Z = z·squeeze + c,
        np.copyto(z, np.nan, where=m)  # NaN at points above the surface
        z += c
        np.subtract(px[lo:hi], qx, out=r2)
        np.square(r2, out=r2)
        np.subtract(py[lo:hi], qy, out=ww)
        r2 += np.square(ww, out=ww)  # ρ² = dx² + dy²
        zz = np.square(z, out=z)  # Z²
        r = np.divide(zz, np.add(r2, zz, out=r2), out=r2)  # r = Z²/(ρ² + Z²)
        # Z⁶/(ρ² + Z²)⁵ = r⁵ / Z⁴, written with products (much faster than ** on arrays): w = r²·r²·r / (Z²·Z²)
        np.square(r, out=ww)
        np.square(ww, out=ww)
        ww *= r
        ww /= np.square(zz, out=zz)
        np.copyto(ww, 0.0, where=np.isnan(ww, out=m))
        ww *= weight[lo:hi]
        ww.sum(axis=1, out=sums[lo:hi])
    return (4.0 * c / math.pi) * sums


def synthesize_force_maps(
    xs_mm: np.ndarray,
    ys_mm: np.ndarray,
    depths_mm: np.ndarray,
    thickness_mm: np.ndarray,
    nodules: tuple[Nodule, ...],
    nodule_center_z: tuple[float, ...],
    *,
    tissue_kpa: float,
    indenter_radius_mm: float,
    rolling_coefficient: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free normal and horizontal force stacks (depth, x, y) in N from the model of this module."""
    xg, yg = np.meshgrid(xs_mm, ys_mm, indexing="ij")
    px, py, th = xg.ravel(), yg.ravel(), np.asarray(thickness_mm, dtype=float).ravel()
    if np.any(th <= 0):
        raise ModelParameterError("synthetic phantom: the surface height must be positive over the mapped area")
    normal = np.empty((len(depths_mm), len(xs_mm), len(ys_mm)))
    for k, d in enumerate(depths_mm):
        log_ratio = np.zeros(px.shape)
        for nod, cz in zip(nodules, nodule_center_z, strict=True):
            # The kernel falls as (Z²/(ρ² + Z²))⁵: beyond ρ = 2.5 Z it is below 1e-4 of its value straight
            # above, so columns farther than that from the nodule's deepest point are skipped.
            z_max = nod.top_depth_mm + nod.diameter_mm + math.sqrt(indenter_radius_mm * float(d))
            reach = 2.5 * z_max + nod.diameter_mm / 2.0
            near = (px - nod.x_mm) ** 2 + (py - nod.y_mm) ** 2 <= reach**2
            phi = nodule_weight(px[near], py[near], th[near], float(d), nod, cz, indenter_radius_mm)
            log_ratio[near] += phi * math.log(nod.modulus_kpa / tissue_kpa)
        e_eff = tissue_kpa * np.exp(log_ratio)
        f = hertz_force_n(e_eff, indenter_radius_mm, d) * bonded_layer_factor(indenter_radius_mm, d, th)
        normal[k] = f.reshape(len(xs_mm), len(ys_mm))
    return normal, rolling_coefficient * normal


@lru_cache(maxsize=8)
def _cached_forces(key: tuple) -> tuple[np.ndarray, np.ndarray]:
    (xs, ys, depths, thickness_shape, thickness, nodules, centers, tissue, radius, mu) = key
    n, h = synthesize_force_maps(
        np.array(xs),
        np.array(ys),
        np.array(depths),
        np.array(thickness).reshape(thickness_shape),
        nodules,
        centers,
        tissue_kpa=tissue,
        indenter_radius_mm=radius,
        rolling_coefficient=mu,
    )
    n.setflags(write=False)
    h.setflags(write=False)
    return n, h


def _check_positive(**values: float) -> None:
    for name, value in values.items():
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ModelParameterError(f"synthetic phantom: {name} is {value!r}; it must be a positive number")


def _build(
    name: str,
    rng: np.random.Generator,
    xs: np.ndarray,
    ys: np.ndarray,
    depths: np.ndarray,
    height_fn,
    surface_xs: np.ndarray,
    surface_ys: np.ndarray,
    nodules: tuple[Nodule, ...],
    parameters: dict[str, Any],
) -> SyntheticPhantom:
    # The material comes from the record the phantom keeps, so what is built and what is stored cannot differ.
    tissue_kpa = parameters["tissue_kpa"]
    indenter_radius_mm = parameters["indenter_radius_mm"]
    rolling_coefficient = parameters["rolling_coefficient"]
    noise_n = parameters["noise_n"]
    if not isinstance(rng, np.random.Generator):
        raise ModelParameterError("synthetic phantom: rng must be a numpy.random.Generator (seeded by the caller)")
    if not (math.isfinite(noise_n) and noise_n >= 0):
        raise ModelParameterError(f"synthetic phantom: noise_n is {noise_n!r}; it must be ≥ 0 N")
    if not (math.isfinite(rolling_coefficient) and rolling_coefficient >= 0):
        raise ModelParameterError(f"synthetic phantom: rolling_coefficient is {rolling_coefficient!r}; it must be ≥ 0")
    _check_positive(tissue_kpa=tissue_kpa, indenter_radius_mm=indenter_radius_mm)
    for nod in nodules:
        _check_positive(
            **{f"nodule {nod.name} diameter_mm": nod.diameter_mm, f"nodule {nod.name} modulus_kpa": nod.modulus_kpa}
        )
        if nod.top_depth_mm < 0:
            raise ModelParameterError(
                f"synthetic phantom: nodule {nod.name} top_depth_mm is {nod.top_depth_mm}; must be ≥ 0"
            )
    xg, yg = np.meshgrid(xs, ys, indexing="ij")
    thickness = height_fn(xg, yg)
    centers = tuple(float(height_fn(n.x_mm, n.y_mm)) - n.top_depth_mm - n.diameter_mm / 2.0 for n in nodules)
    for nod, cz in zip(nodules, centers, strict=True):
        if cz - nod.diameter_mm / 2.0 < 0:
            raise ModelParameterError(
                f"synthetic phantom: nodule {nod.name} reaches below the table; make it shallower"
            )
    key = (
        tuple(np.round(xs, 9)),
        tuple(np.round(ys, 9)),
        tuple(np.round(depths, 9)),
        thickness.shape,
        tuple(np.round(thickness.ravel(), 9)),
        nodules,
        centers,
        float(tissue_kpa),
        float(indenter_radius_mm),
        float(rolling_coefficient),
    )
    normal, horizontal = _cached_forces(key)
    if noise_n > 0:
        normal = normal + rng.normal(0.0, noise_n, normal.shape)
        horizontal = horizontal + rng.normal(0.0, noise_n, horizontal.shape)
    sx, sy = np.meshgrid(surface_xs, surface_ys, indexing="ij")
    heights = np.asarray(height_fn(sx, sy), dtype=float)
    stiffness = StiffnessMap.from_arrays(
        np.array(normal),
        depths,
        dx_mm=float(xs[1] - xs[0]),
        dy_mm=float(ys[1] - ys[0]),
        horizontal=np.array(horizontal),
        x0_mm=float(xs[0]),
        y0_mm=float(ys[0]),
        source=f"synthetic {name} (approximation, not a measurement)",
        notes=(
            "Hertz sphere + Dimitriadis bonded layer + Lichtenecker log mixing of nodules weighted by the "
            "Boussinesq strain-energy kernel; see studyctl.models.synthetic_phantom",
        ),
    )
    for arr in (surface_xs, surface_ys, heights):
        arr.setflags(write=False)
    return SyntheticPhantom(name, stiffness, surface_xs, surface_ys, heights, nodules, parameters)


SEED003_NODULES = (
    # Positions are chosen (seed 003 does not print them); sizes, depth and moduli are the paper's.
    Nodule("A", 30.0, 85.0, 10.0, 6.0, 1590.0),
    Nodule("B", 85.0, 80.0, 8.0, 6.0, 1590.0),
    Nodule("C", 60.0, 35.0, 6.0, 6.0, 1590.0),
)


def silicone_block_003(
    rng: np.random.Generator,
    *,
    nodules: tuple[Nodule, ...] = SEED003_NODULES,
    tissue_kpa: float = 15.3,
    indenter_radius_mm: float = 5.0,
    rolling_coefficient: float = 0.05,
    noise_n: float = 0.003,
) -> SyntheticPhantom:
    """The seed 003 silicone block: 120 × 120 × 25 mm, RTV6166 3:7 (15.3 kPa), nodules of 10, 8 and 6 mm
    (about 1.59 MPa) with their tops 6 mm below the surface, six 159 × 59 force matrices at 2–7 mm.

    Chosen where the paper is silent or inconsistent: nodule positions (:data:`SEED003_NODULES`); the
    indenter radius (5 mm, inside the 6–10 mm diameters of its §2.3); x nodes spanning the 120 mm block
    (159 nodes, 0.766 mm apart); y nodes 2 mm apart from 2 to 118 mm, because 59 paths 4 mm apart (as
    printed) would span 232 mm, wider than the block. The block frame has its origin at a corner, x and
    y along the edges, z up from the table; the scene rotates it per trial.
    """
    xs = np.linspace(0.0, 120.0, 159)
    ys = 2.0 + 2.0 * np.arange(59)
    depths = np.arange(2.0, 8.0)

    def height(x, y):
        return np.full(np.broadcast(np.asarray(x), np.asarray(y)).shape, 25.0)

    parameters = {
        "block_mm": (120.0, 120.0, 25.0),
        "tissue_kpa": tissue_kpa,
        "indenter_radius_mm": indenter_radius_mm,
        "rolling_coefficient": rolling_coefficient,
        "noise_n": noise_n,
    }
    return _build(
        "seed003_block",
        rng,
        xs,
        ys,
        depths,
        height,
        np.array([0.0, 120.0]),
        np.array([0.0, 120.0]),
        nodules,
        parameters,
    )


SEED002_NODULES = (
    # Positions chosen; 15 mm diameter, tops 3 mm deep as in seed 002. Moduli are not given there: the
    # seed 003 values for the same silicone family are reused.
    Nodule("A", 30.0, 45.0, 15.0, 3.0, 1590.0),
    Nodule("B", 62.0, 28.0, 15.0, 3.0, 1590.0),
)


def curved_phantom_002(
    rng: np.random.Generator,
    *,
    nodules: tuple[Nodule, ...] = SEED002_NODULES,
    tissue_kpa: float = 15.3,
    indenter_radius_mm: float = 5.0,
    rolling_coefficient: float = 0.05,
    noise_n: float = 0.003,
    center_height_mm: float = 25.0,
    edge_height_mm: float = 10.0,
) -> SyntheticPhantom:
    """The seed 002 phantom: a curved silicone surface with two 15 mm nodules 3 mm deep; normal and
    horizontal force maps at 2, 4 and 6 mm; a 31 × 26 node surface grid (1500 triangles, as displayed
    in the paper).

    Chosen: a 90 × 75 mm footprint, a dome ``h = h_e + (h_c − h_e)(1 − u²)(1 − v²)`` with ``u``, ``v`` the
    normalised distances from the centre (25 mm high in the middle, 10 mm at the edges), a 1.5 mm map
    grid from 3 mm inside the edges, nodule positions. The thin edges make the tissue stiffer there (the
    bonded-layer term), as seed 002's false reports at the edges suggest real phantoms do.
    """
    _check_positive(center_height_mm=center_height_mm, edge_height_mm=edge_height_mm)
    width, depth_y = 90.0, 75.0

    def height(x, y):
        u = (np.asarray(x) - width / 2) / (width / 2)
        v = (np.asarray(y) - depth_y / 2) / (depth_y / 2)
        return edge_height_mm + (center_height_mm - edge_height_mm) * np.clip(1 - u**2, 0, 1) * np.clip(1 - v**2, 0, 1)

    xs = np.arange(3.0, 87.0 + 1e-9, 1.5)
    ys = np.arange(3.0, 72.0 + 1e-9, 1.5)
    parameters = {
        "footprint_mm": (width, depth_y),
        "center_height_mm": center_height_mm,
        "edge_height_mm": edge_height_mm,
        "tissue_kpa": tissue_kpa,
        "indenter_radius_mm": indenter_radius_mm,
        "rolling_coefficient": rolling_coefficient,
        "noise_n": noise_n,
    }
    return _build(
        "seed002_curved",
        rng,
        xs,
        ys,
        np.array([2.0, 4.0, 6.0]),
        height,
        np.linspace(0.0, width, 31),
        np.linspace(0.0, depth_y, 26),
        nodules,
        parameters,
    )


PHANTOMS = {"seed003_block": silicone_block_003, "seed002_curved": curved_phantom_002}
