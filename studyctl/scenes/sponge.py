"""The sponge phantom of seed 000: a 14 × 14 × 4.8 cm sponge with 7 holes in its base for tumours.

Facts from the paper: the sponge (QEP 70005Q-6D, 14 × 14 × 4.8 cm, E ≈ 50 kPa); 7 holes in the base;
soft / medium / hard tumours of foam, silica gel and rubber (E ≈ 58 / 70 / 120 kPa), about 1 cm in
diameter and 3 cm high, inserted from the base; a coordinate grid drawn on top; reports by column and row.

**Chosen** here (the paper gives no numbers for them): the hole layout (a hexagon of six holes 45 mm
around a central one — Fig. 5 shows 7 holes but no coordinates); empty holes hold sponge plugs (no
contrast); the probe is a flat disc of radius 4.75 mm (the FlexiForce A201's 9.53 mm sensing area);
sponge Poisson ratio 0.3; the force model below.

Force model: a flat punch on an elastic half-space (Sneddon), ``F = 2·a·E*·d`` with ``E* = E/(1 − ν²)``,
scaled over a tumour by the stiffness ratio of the material column under the probe — sponge above the
tumour in series with the tumour, against sponge alone: ``ρ = H / (z + h·E_sponge/E_tumour)`` (1.09 soft,
1.22 medium, 1.57 hard) — weighted by the lateral overlap ``exp(−r²/2σ²)``, σ = 8 mm. Forces are
reported as the sensor sees them: newtons, and kPa over the sensing area.

Only what the trial needs is built: a model per placed tumour (none for empty holes) and the top view
only when ``needs`` contains ``view``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.plugins.interfaces import Channels, Scene
from studyctl.plugins.params import Param, problems_with_rules, validate_params

_NONE: Mapping[str, Any] = MappingProxyType({})

TUMOUR_MODULUS_KPA = {"soft": 58.0, "medium": 70.0, "hard": 120.0}  # paper, Methods D.2


def hexagon_holes(center_mm: tuple[float, float] = (70.0, 70.0), radius_mm: float = 45.0) -> tuple:
    """Hole centres 1-6 on a hexagon (counter-clockwise from +x), hole 7 in the middle (chosen layout)."""
    cx, cy = center_mm
    ring = tuple(
        (round(cx + radius_mm * math.cos(k * math.pi / 3), 3), round(cy + radius_mm * math.sin(k * math.pi / 3), 3))
        for k in range(6)
    )
    return ring + ((cx, cy),)


@dataclass(frozen=True)
class Tumour:
    """A placed tumour: class, hole (1-based), centre (mm), radius and the column stiffness ratio."""

    cls: str
    hole: int
    x_mm: float
    y_mm: float
    radius_mm: float
    modulus_kpa: float
    stiffness_ratio: float


@dataclass(frozen=True)
class Grid:
    """The coordinate grid drawn on the phantom: 1-based columns along x and rows along y."""

    columns: int
    rows: int
    cell_mm: float
    origin_mm: tuple[float, float] = (0.0, 0.0)

    def cell_of(self, x_mm: float, y_mm: float) -> tuple[int, int]:
        col = int(math.floor((x_mm - self.origin_mm[0]) / self.cell_mm)) + 1
        row = int(math.floor((y_mm - self.origin_mm[1]) / self.cell_mm)) + 1
        return min(max(col, 1), self.columns), min(max(row, 1), self.rows)

    def center_of(self, col: int, row: int) -> tuple[float, float]:
        return (self.origin_mm[0] + (col - 0.5) * self.cell_mm, self.origin_mm[1] + (row - 0.5) * self.cell_mm)

    def as_dict(self) -> dict[str, Any]:
        return {"columns": self.columns, "rows": self.rows, "cell_mm": self.cell_mm, "origin_mm": list(self.origin_mm)}


class SpongePhantomScene(Scene):
    """Sponge phantom with soft/medium/hard tumours in 7 holes: sensor force for probe position and depth."""

    name = "sponge_phantom"
    PARAMS = (
        Param("size_mm", (140.0, 140.0, 48.0), kind=tuple, source="paper: QEP 70005Q-6D 14x14x4.8 cm"),
        Param("sponge_kpa", 50.0, 1.0, 1000.0, unit="kPa", source="paper: sponge E ≈ 50 kPa"),
        Param("sponge_poisson", 0.3, 0.0, 0.49, source="CHOSEN: typical open-cell foam"),
        Param("tumour_kpa", TUMOUR_MODULUS_KPA, kind=dict, source="paper: S/M/H ≈ 58/70/120 kPa"),
        Param("tumour_diameter_mm", 10.0, 1.0, 40.0, unit="mm", source="paper: about 1 cm"),
        Param("tumour_height_mm", 30.0, 1.0, 47.0, unit="mm", source="paper: about 3 cm"),
        Param("holes_mm", hexagon_holes(), kind=tuple, source="CHOSEN: hexagon of 6 + 1 (Fig. 5 has no coordinates)"),
        Param("probe_radius_mm", 4.75, 0.5, 20.0, unit="mm", source="FlexiForce A201 sensing area 9.53 mm"),
        Param("lateral_sigma_mm", 8.0, 0.5, 50.0, unit="mm", source="CHOSEN: overlap of probe and tumour, spread"),
        Param("grid", {"columns": 7, "rows": 7, "cell_mm": 20.0}, kind=dict,
              source="protocols/bio_inspired_palpation.yaml report grid (7 x 7, 20 mm)"),
        Param("sensing_diameter_mm", 9.53, 1.0, 50.0, unit="mm", source="FlexiForce A201 datasheet"),
    )

    # protocol check: every refused value at its key, and the geometry rules between them
    param_problems = problems_with_rules(
        PARAMS, lambda p, spec=PARAMS: _check_geometry(validate_params("sponge_phantom scene", p, spec)),
        "sponge_phantom scene: ",
    )

    def __init__(self, params: Mapping[str, Any], tumours: tuple[Tumour, ...], needs: frozenset[str]) -> None:
        self.params = params
        self.tumours = tumours
        self.needs = needs
        sx, sy, sz = params["size_mm"]
        self.size_mm = (float(sx), float(sy), float(sz))
        e_star = params["sponge_kpa"] * 1e3 / (1 - params["sponge_poisson"] ** 2)
        self.k_contact_n_per_mm = 2 * params["probe_radius_mm"] * 1e-3 * e_star * 1e-3  # N per mm of depth
        self.sigma_mm = float(params["lateral_sigma_mm"])
        # force_n runs twice per tick (the forceps' contact): its constants computed once, the same floats
        self._two_s2 = 2 * self.sigma_mm**2
        self._spots = tuple((t.x_mm, t.y_mm, t.stiffness_ratio - 1.0) for t in tumours)
        g = params["grid"]
        self.grid = Grid(int(g["columns"]), int(g["rows"]), float(g["cell_mm"]), tuple(g.get("origin_mm", (0.0, 0.0))))
        self._grid_view = self.grid.as_dict()
        self.sensing_area_m2 = math.pi * (params["sensing_diameter_mm"] * 1e-3 / 2) ** 2
        # What was built, for inspection and tests: the sponge, one model per placed tumour, the view.
        self.parts = frozenset({"sponge", *(f"tumour:{t.cls}" for t in tumours), *({"view"} & needs)})

    @classmethod
    def build(
        cls, spec: Mapping[str, Any], placement: Mapping[str, Any], needs: frozenset[str], rng: np.random.Generator
    ) -> SpongePhantomScene:
        """Build from the protocol's scene spec (``params`` inside it, optional) and the trial's placement.

        ``placement`` is ``{"sites": {"soft": 3, "medium": 5, "hard": 1}}`` (1-based holes), as the
        schedule stores it; a plain ``{"soft": 3, ...}`` mapping is accepted too.
        """
        # The engine passes the protocol's scene params directly; {"params": {...}} is accepted too.
        raw = dict((spec.get("params", spec) if isinstance(spec, Mapping) else {}) or {})
        params = validate_params("sponge_phantom scene", raw, cls.PARAMS)
        _check_geometry(params)
        sites = placement.get("sites", placement) if isinstance(placement, Mapping) else {}
        sites = {k: v for k, v in dict(sites or {}).items() if k != "orientation_deg"}
        holes = params["holes_mm"]
        moduli = params["tumour_kpa"]
        h_total = float(params["size_mm"][2])
        h_t = float(params["tumour_height_mm"])
        e_s = float(params["sponge_kpa"])
        used: dict[int, str] = {}
        tumours = []
        for cls_name, hole in sorted(sites.items()):
            if cls_name not in moduli:
                raise ModelParameterError(
                    f"sponge_phantom scene: placement names tumour {cls_name!r}; known classes: {', '.join(moduli)}"
                )
            if not isinstance(hole, int) or not 1 <= hole <= len(holes):
                raise ModelParameterError(
                    f"sponge_phantom scene: tumour {cls_name!r} is in hole {hole!r}; holes are 1..{len(holes)}"
                )
            if hole in used:
                raise ModelParameterError(
                    f"sponge_phantom scene: tumours {used[hole]!r} and {cls_name!r} are both placed in hole {hole}"
                )
            used[hole] = cls_name
            e_t = float(moduli[cls_name])
            ratio = h_total / ((h_total - h_t) + h_t * e_s / e_t)
            x, y = holes[hole - 1]
            tumours.append(
                Tumour(cls_name, hole, float(x), float(y), params["tumour_diameter_mm"] / 2, e_t, ratio)
            )
        return cls(params, tuple(tumours), frozenset(needs))

    # -- sensing -------------------------------------------------------------------------------------
    def force_n(self, x_mm: float, y_mm: float, depth_mm: float) -> float:
        """Force on the probe pressed ``depth_mm`` into the sponge surface at (x, y)."""
        sx, sy, sz = self.size_mm
        if not (depth_mm > 0) or not (0 <= x_mm <= sx and 0 <= y_mm <= sy):
            return 0.0
        depth = sz if sz < depth_mm else depth_mm  # min(depth_mm, sz)
        scale = 1.0
        two_s2 = self._two_s2
        for tx, ty, excess in self._spots:  # three at most: plain floats beat numpy here
            r2 = (tx - x_mm) ** 2 + (ty - y_mm) ** 2
            scale += excess * math.exp(-r2 / two_s2)
        return self.k_contact_n_per_mm * depth * scale

    def sense(self, inputs: Channels) -> dict[str, float]:
        """``force_n`` and ``pressure_kpa`` for inputs ``x_mm``, ``y_mm``, ``depth_mm`` (missing = no contact)."""
        f = self.force_n(
            float(inputs.get("x_mm", -1.0)), float(inputs.get("y_mm", -1.0)), float(inputs.get("depth_mm", 0.0))
        )
        return {"force_n": f, "pressure_kpa": f / self.sensing_area_m2 / 1e3}

    def view(self, inputs: Channels) -> Mapping[str, Any] | None:
        """Top view (probe position and grid; the tumours are hidden under the sponge), if built."""
        return self.view_parts(inputs, _NONE, _NONE)

    def view_parts(self, a: Channels, b: Channels, c: Channels) -> Mapping[str, Any] | None:
        """``view({**a, **b, **c})`` without merging the three mappings (a channel in a later one wins): the
        trial loop's real-time view asks this every tick with the participant's inputs, the device's
        observation and the controller's diagnostics."""
        if "view" not in self.parts:
            return None
        x = c["x_mm"] if "x_mm" in c else b["x_mm"] if "x_mm" in b else a.get("x_mm", -1.0)
        y = c["y_mm"] if "y_mm" in c else b["y_mm"] if "y_mm" in b else a.get("y_mm", -1.0)
        depth = c["depth_mm"] if "depth_mm" in c else b["depth_mm"] if "depth_mm" in b else a.get("depth_mm", 0.0)
        # the grid is the same every frame: one dict for all frames (read it, never change it), not one per tick
        return {"probe_mm": (float(x), float(y)), "depth_mm": float(depth), "grid": self._grid_view,
                "size_mm": self.size_mm}

    # -- knowledge -----------------------------------------------------------------------------------
    def public(self) -> Mapping[str, Any]:
        return {"grid": self.grid.as_dict(), "size_mm": list(self.size_mm), "holes": len(self.params["holes_mm"])}

    def marks(self) -> tuple[dict[str, Any], ...]:
        """The sites as drawn on an example phantom (seed 000: "the locations of 3 different types of tumors were
        marked"): class, centre and grid cell of each placed tumour. The engine shows them only in practice."""
        cells = [self.grid.cell_of(t.x_mm, t.y_mm) for t in self.tumours]
        return tuple({"class": t.cls, "x_mm": t.x_mm, "y_mm": t.y_mm, "col": col, "row": row}
                     for t, (col, row) in zip(self.tumours, cells, strict=True))

    def truth(self) -> Mapping[str, Any]:
        return {
            "tumours": [
                {"class": t.cls, "hole": t.hole, "x_mm": t.x_mm, "y_mm": t.y_mm, "radius_mm": t.radius_mm,
                 "col": self.grid.cell_of(t.x_mm, t.y_mm)[0], "row": self.grid.cell_of(t.x_mm, t.y_mm)[1],
                 "modulus_kpa": t.modulus_kpa, "stiffness_ratio": t.stiffness_ratio}
                for t in self.tumours
            ],
            "grid": self.grid.as_dict(),
            "probe_radius_mm": self.params["probe_radius_mm"],
        }


def tumour_under_probe(truth: Mapping[str, Any], x_mm: float, y_mm: float) -> str | None:
    """The class of the tumour the probe footprint overlaps at (x, y), or None (for contact metrics)."""
    reach = float(truth.get("probe_radius_mm", 0.0))
    for t in truth.get("tumours", ()):
        if math.hypot(t["x_mm"] - x_mm, t["y_mm"] - y_mm) <= t["radius_mm"] + reach:
            return str(t["class"])
    return None


def _check_geometry(params: Mapping[str, Any]) -> None:
    size = params["size_mm"]
    if len(size) != 3 or not all(isinstance(v, int | float) and v > 0 for v in size):
        raise ModelParameterError(f"sponge_phantom scene: size_mm {list(size)} must be three positive lengths")
    if params["tumour_height_mm"] >= size[2]:
        raise ModelParameterError(
            f"sponge_phantom scene: tumour_height_mm {params['tumour_height_mm']} must be below the sponge "
            f"thickness {size[2]} mm"
        )
    for i, hole in enumerate(params["holes_mm"], 1):
        if len(hole) != 2 or not (0 <= hole[0] <= size[0] and 0 <= hole[1] <= size[1]):
            raise ModelParameterError(f"sponge_phantom scene: hole {i} at {list(hole)} lies outside the sponge")
    for cls_name, e in params["tumour_kpa"].items():
        if not isinstance(e, int | float) or not 0 < e <= 1e5:
            raise ModelParameterError(f"sponge_phantom scene: tumour_kpa[{cls_name!r}] = {e!r} must be in (0, 1e5]")
    g = params["grid"]
    try:
        ok = int(g["columns"]) >= 1 and int(g["rows"]) >= 1 and float(g["cell_mm"]) > 0
    except (KeyError, TypeError, ValueError):
        ok = False
    if not ok:
        raise ModelParameterError(
            f"sponge_phantom scene: grid {g!r} needs columns ≥ 1, rows ≥ 1 and cell_mm > 0"
        )
