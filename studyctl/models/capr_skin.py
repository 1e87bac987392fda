"""CAPR skin and population: the fingertip outline, the flat-disc contact, each afferent type's units with
their network gains, and reduced populations (speed against error). The model that runs them is
:mod:`studyctl.models.capr`."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from studyctl.errors import ModelParameterError
from studyctl.models.capr_afferents import AfferentType

# --------------------------------------------------------------------------------------------------
# Population geometry and skin mechanics
# --------------------------------------------------------------------------------------------------


def fingertip_outline() -> np.ndarray:
    """The fingertip outline (20 vertices, mm) of the CAPR code, centred on its bounding-box midpoint."""
    return _outline().copy()


@lru_cache(maxsize=1)
def _outline() -> np.ndarray:
    path = Path(__file__).with_name("fingertip_roi.csv")
    pts = np.loadtxt(path, delimiter=",", comments="#", skiprows=5)
    mid = (pts.max(axis=0) + pts.min(axis=0)) / 2
    return pts - mid


def inside_polygon(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Even-odd ray-casting test of points (n, 2) against a closed polygon (k, 2)."""
    x, y = pts[:, 0], pts[:, 1]
    inside = np.zeros(len(pts), dtype=bool)
    k = len(poly)
    for i in range(k):
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % k]
        if y1 == y2:
            continue
        crosses = (y1 > y) != (y2 > y)
        xcross = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < xcross)
    return inside


@dataclass(frozen=True)
class SkinContact:
    """The stimulus: a flat disc pressed on the fingertip with the sensor's force.

    Sources: radius 4 mm and disc height 5 mm are the BHF code's sensor stimulus (``rad=4``,
    ``probeh=5``); skin E = 50 kPa, ν = 0.4 and 0.2 mm skin pixels are the CAPR code's.
    """

    radius_mm: float = 4.0
    height_mm: float = 5.0
    center_mm: tuple[float, float] = (0.0, 0.0)
    youngs_pa: float = 50e3
    poisson: float = 0.4
    pixel_mm: float = 0.2

    def __post_init__(self) -> None:
        if not (0 < self.radius_mm <= 20 and 0 < self.height_mm <= 50 and 0 < self.pixel_mm <= 1):
            raise ModelParameterError(
                f"skin contact: radius {self.radius_mm} mm (0-20], height {self.height_mm} mm (0-50] and pixel "
                f"{self.pixel_mm} mm (0-1] must be positive and in range"
            )
        if not (self.youngs_pa > 0 and 0 <= self.poisson < 0.5):
            raise ModelParameterError(f"skin contact: E = {self.youngs_pa} Pa must be > 0 and ν in [0, 0.5)")

    @property
    def compliance(self) -> float:
        """C_m = (1 − ν²)/(2E), m/Pa (CAPR code)."""
        return (1 - self.poisson**2) / (2 * self.youngs_pa)


@dataclass(frozen=True)
class Population:
    """One afferent type's units on the fingertip and their gains for a given contact.

    ``gain_contact`` (k) and ``gain_deep`` (m), in volts per newton, give each unit's network input
    ``U_c = k·F + m·max(0, F − force_crit_n)``. ``weights`` count how many original units a unit stands
    for (1 in the full model; more in clustered reductions).
    """

    afferent: AfferentType
    positions_mm: np.ndarray
    grid: np.ndarray
    in_contact: np.ndarray
    gain_contact: np.ndarray
    gain_deep: np.ndarray
    force_crit_n: float
    weights: np.ndarray
    label: str = "full"
    # The spatial stage before it was folded into the gains (kept for the reference-structure peer of
    # ``studyctl bench capr``): current per metre of indentation of each unit, indentation per newton, disc height.
    current_per_m: np.ndarray | None = None
    alpha_m_per_n: float = 0.0
    height_m: float = 0.0

    @property
    def size(self) -> int:
        return int(self.gain_contact.size)

    def to_frame(self) -> pd.DataFrame:
        """One row per unit: type, x_mm, y_mm, in_contact, gain_contact, gain_deep, weight."""
        return pd.DataFrame(
            {
                "type": self.afferent.name,
                "x_mm": self.positions_mm[:, 0],
                "y_mm": self.positions_mm[:, 1],
                "in_contact": self.in_contact,
                "gain_contact": self.gain_contact,
                "gain_deep": self.gain_deep,
                "weight": self.weights,
            },
            columns=["type", "x_mm", "y_mm", "in_contact", "gain_contact", "gain_deep", "weight"],
        )

    def subset(self, keep: np.ndarray, label: str, weights: np.ndarray | None = None) -> Population:
        keep = np.asarray(keep)
        w = self.weights[keep] if weights is None else np.asarray(weights, dtype=float)
        return replace(
            self,
            current_per_m=None if self.current_per_m is None else self.current_per_m[keep],
            positions_mm=self.positions_mm[keep],
            grid=self.grid[keep],
            in_contact=self.in_contact[keep],
            gain_contact=self.gain_contact[keep],
            gain_deep=self.gain_deep[keep],
            weights=w,
            label=label,
        )


def unit_grid(t: AfferentType, outline: np.ndarray | None = None, theta: float = 3 * math.pi / 4):
    """Unit positions (mm) and integer grid indices: a square grid of pitch 10/√density mm rotated by −θ
    and clipped to the outline (CAPR code ``sim_all_setup``; gives 164/319/56 SA1/RA1/PC units)."""
    roi = _outline() if outline is None else outline
    pitch = 10.0 / math.sqrt(t.density_per_cm2)
    reach = int(np.sqrt((roi**2).sum(axis=1)).max() / pitch)
    ii, jj = np.meshgrid(np.arange(-reach, reach + 1), np.arange(-reach, reach + 1))
    grid = np.column_stack([ii.ravel(), jj.ravel()])
    c, s = math.cos(-theta), math.sin(-theta)
    rot = np.array([[c, s], [-s, c]])  # row-vector convention of the CAPR code: p' = p @ rot
    pos = (grid * pitch) @ rot
    keep = inside_polygon(roi, pos)
    return pos[keep], grid[keep]


def build_population(
    t: AfferentType, contact: SkinContact | None = None, outline: np.ndarray | None = None
) -> Population:
    """Units of type ``t`` on the fingertip and their network gains for a flat-disc ``contact``.

    Skin pixels (pitch ``pixel_mm·n_ds``) inside the outline are assigned to their nearest unit; a unit
    whose patch holds disc pixels is "in contact" and is indented by the disc's depth ``D_p = α·F``; the
    others only once ``D_p`` exceeds the disc height. Each patch is padded with its unit's own pixel to
    the size of the largest patch before the height variance is taken, as in the CAPR code. The
    network ``G`` has ``4/C_d`` on the diagonal and −1 for each of the four grid neighbours.
    """
    contact = contact or SkinContact()
    roi = _outline() if outline is None else outline
    pos, grid = unit_grid(t, roi)
    n = len(pos)
    if n == 0:
        raise ModelParameterError(f"CAPR {t.name}: no units fit in the outline at {t.density_per_cm2}/cm²")
    pitch = contact.pixel_mm * t.n_ds
    lo, hi = roi.min(axis=0), roi.max(axis=0)
    xs = lo[0] + pitch * np.arange(int((hi[0] - lo[0]) / pitch))
    ys = lo[1] + pitch * np.arange(int((hi[1] - lo[1]) / pitch))
    px, py = np.meshgrid(xs, ys)
    pix = np.column_stack([px.ravel(), py.ravel()])
    cx, cy = contact.center_mm
    in_disc_all = (pix[:, 0] - cx) ** 2 + (pix[:, 1] - cy) ** 2 <= contact.radius_mm**2
    n_contact_px = int(in_disc_all.sum())  # the CAPR code counts disc pixels over the whole window
    if n_contact_px == 0:
        raise ModelParameterError("skin contact: the disc covers no skin pixel; enlarge radius_mm")
    inside = inside_polygon(roi, pix)
    pix, in_disc = pix[inside], in_disc_all[inside]
    # nearest unit of every skin pixel
    d2 = ((pix[:, None, :] - pos[None, :, :]) ** 2).sum(axis=2)
    owner = d2.argmin(axis=1)
    counts = np.bincount(owner, minlength=n)
    heights = np.where(in_disc, contact.height_mm, 0.0)
    own_height = np.where((pos[:, 0] - cx) ** 2 + (pos[:, 1] - cy) ** 2 <= contact.radius_mm**2, contact.height_mm, 0.0)
    n_max = int(counts.max())
    # variance of the padded patch: patch pixels plus (n_max - count) copies of the unit's own pixel
    s1 = np.bincount(owner, weights=heights, minlength=n) + (n_max - counts) * own_height
    s2 = np.bincount(owner, weights=heights**2, minlength=n) + (n_max - counts) * own_height**2
    var = np.maximum(s2 / n_max - (s1 / n_max) ** 2, 0.0)
    touched = np.bincount(owner, weights=in_disc.astype(float), minlength=n) > 0
    in_contact = touched | (own_height > 0)
    gi_mat = network_matrix(t, grid)
    alpha = contact.compliance / (t.n_ds * contact.pixel_mm * 1e-3 * math.sqrt(n_contact_px / 4.0))  # m per N
    current = t.c_s + t.c_e * var  # per metre of indentation
    k = alpha * gi_mat @ np.where(in_contact, current, 0.0)
    m = alpha * gi_mat @ np.where(in_contact, 0.0, current)
    force_crit = contact.height_mm * 1e-3 / alpha
    return Population(t, pos, grid, in_contact, k, m, force_crit, np.ones(n), "full",
                      current_per_m=np.asarray(current, dtype=float), alpha_m_per_n=alpha,
                      height_m=contact.height_mm * 1e-3)


def network_matrix(t: AfferentType, grid: np.ndarray) -> np.ndarray:
    """``R_c·G⁻¹`` of the resistance network: G has ``4/C_d`` on the diagonal, −1 per grid neighbour."""
    n = len(grid)
    index = {tuple(g): i for i, g in enumerate(grid)}
    g_mat = np.eye(n) * (4.0 / t.c_d)
    for i, (gi, gj) in enumerate(grid):
        for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            j = index.get((gi + di, gj + dj))
            if j is not None:
                g_mat[i, j] = -1.0
    return t.r_c * np.linalg.inv(g_mat)


# --------------------------------------------------------------------------------------------------
# Reduced populations (speed against error; see ``studyctl bench capr``)
# --------------------------------------------------------------------------------------------------

REDUCTIONS = ("full", "contact", "density", "clusters", "single")


def reduce_population(pop: Population, method: str = "full", *, factor: int = 2, clusters: int = 8) -> Population:
    """A cheaper stand-in for ``pop``.

    ``full``
        unchanged.
    ``contact``
        only the units under the contact disc ("afferents under the contact area").
    ``density``
        a regular subset of the grid, keeping each unit's full-network gains: ``factor`` 2 keeps a
        checkerboard (half the density), 4 every other row and column (a quarter).
    ``clusters``
        ``clusters`` units per type (or all of a smaller type), each standing for a quantile group of units
        sorted by gain (gains averaged, weight = group size), so the activated mean stays a weighted mean.
    ``single``
        one unit: the contact unit with the median contact gain.
    """
    if method == "full":
        return pop
    if method == "contact":
        return pop.subset(np.flatnonzero(pop.in_contact), "contact")
    if method == "density":
        i, j = pop.grid[:, 0], pop.grid[:, 1]
        if factor == 2:
            keep = (i + j) % 2 == 0
        elif factor == 4:
            keep = (i % 2 == 0) & (j % 2 == 0)
        else:
            raise ModelParameterError(f"CAPR: density reduction factor {factor!r} must be 2 or 4")
        return pop.subset(np.flatnonzero(keep), f"density/{factor}")
    if method == "clusters":
        if not 1 <= clusters <= 10_000:
            raise ModelParameterError(f"CAPR: clusters = {clusters} must be in 1..10000")
        order = np.argsort(pop.gain_contact)
        groups = np.array_split(order, min(clusters, pop.size))  # a type with fewer units keeps them all
        w = pop.weights
        k = np.array([np.average(pop.gain_contact[g], weights=w[g]) for g in groups])
        m = np.array([np.average(pop.gain_deep[g], weights=w[g]) for g in groups])
        firsts = np.array([g[0] for g in groups])
        reduced = pop.subset(firsts, f"clusters/{clusters}", weights=np.array([w[g].sum() for g in groups]))
        return replace(reduced, gain_contact=k, gain_deep=m)
    if method == "single":
        idx = np.flatnonzero(pop.in_contact)
        idx = idx[np.argsort(pop.gain_contact[idx])]
        return pop.subset(idx[len(idx) // 2: len(idx) // 2 + 1], "single", weights=np.ones(1))
    raise ModelParameterError(f"CAPR: unknown population reduction {method!r}; use one of {', '.join(REDUCTIONS)}")
