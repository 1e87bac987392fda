"""The liver of seed 001: capsule, liver tissue and a 2.5 mm tumour as nested spheres, and a CT-like view.

Coordinates are the device frame in millimetres (x, y horizontal, z up), so a controller, a scene and a
device agree without a registration step. The paper's spherical RViz markers carry the layer properties;
here the capsule is the surface of the liver sphere and the tumour sphere sits at its centre (its Figure 4).
A trial's placement (stored with the schedule) moves the spheres and picks the incision point on the
capsule; the planned path runs straight from the incision point to the tumour centroid.

The view is two orthogonal CT-like slices through the tumour (an axial plane z = z_tumour and a coronal
plane y = y_tumour) side by side, with the needle projected onto each plane relative to the tumour and a
radio-opaque skin marker at the planned incision point. Frames are cheap to create and render their image
only when someone looks at it, so a real-time condition can ask for a frame every tick.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.models.needle_guidance import NeedleGeometry
from studyctl.plugins.interfaces import Channels, Scene
from studyctl.plugins.params import Param, problems_with_rules

# Grey levels of the synthetic CT (uint8). Bands are far apart (> 5 σ of the texture noise), so that
# a reader can tell the structures apart, as a radiologist tells tissue from metal.
AIR, LIVER_LEVEL, LIVER_NOISE, CAPSULE_LEVEL, TUMOUR_LEVEL, MARKER_LEVEL, NEEDLE_LEVEL = 15, 105, 9, 140, 200, 235, 255

#: The scene's parameters (the protocol's ``scene.params``), checked by ``studyctl protocol check`` with their line;
#: the rules between them (tumour inside the liver) are :func:`_spec`'s.
PARAMS = (
    Param("liver_radius_mm", 55.0, 0.0, None, unit="mm", doc="liver tissue sphere; the capsule is its surface",
          source="CHOSEN: an adult liver lobe's scale; seed 001 gives no size"),
    Param("tumour_diameter_mm", 2.5, 0.0, None, unit="mm", source="seed 001: a 2.5 mm tumour"),
    Param("center_mm", (0.0, 0.0, -25.0), kind=tuple, unit="mm", doc="nominal tumour centroid in the device frame",
          source="CHOSEN: inside the Omega.6 workspace"),
    Param("center_jitter_mm", 5.0, 0.0, None, unit="mm", doc="per-trial uniform jitter of the centroid on each axis",
          source="CHOSEN"),
    Param("approach_max_deg", 35.0, 0.0, 80.0, unit="deg",
          doc="incision point: direction from the tumour within this cone about +z", source="CHOSEN"),
    Param("needle_length_mm", 150.0, 0.0, None, unit="mm", source="CHOSEN: a biopsy needle's length"),
    Param("view_size_px", 256, 32, 2048, kind=int, doc="each slice panel is square", source="CHOSEN"),
    Param("view_mm_per_px", 0.5, 0.0, None, unit="mm/px", source="CHOSEN: a CT slice's pixel size"),
    Param("view_center_mm", (0.0, 0.0, -20.0), kind=tuple, unit="mm",
          doc="device point at the centre of both panels", source="CHOSEN"),
    Param("site_seed", 2024, 0, None, kind=int,
          doc="configurations ('sites') of the protocol's placement are drawn from this seed", source="CHOSEN"),
)
DEFAULT_SPEC: dict[str, Any] = {p.name: p.default for p in PARAMS}


def _vec3(value: Any, name: str) -> tuple[float, float, float]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ModelParameterError(
            f"scene needle_liver: {name} = {value!r} must be three numbers [x, y, z] in mm"
        ) from None
    if len(out) != 3 or not all(math.isfinite(v) for v in out):
        raise ModelParameterError(f"scene needle_liver: {name} = {value!r} must be three finite numbers in mm")
    return out  # type: ignore[return-value]


def _spec(spec: Mapping[str, Any]) -> dict[str, Any]:
    unknown = sorted(set(spec) - set(DEFAULT_SPEC))
    if unknown:
        raise ModelParameterError(
            f"scene needle_liver: unknown field(s) {', '.join(unknown)}; allowed: {', '.join(DEFAULT_SPEC)}"
        )
    out = {**DEFAULT_SPEC, **spec}
    for key in ("liver_radius_mm", "tumour_diameter_mm", "needle_length_mm", "view_mm_per_px"):
        v = out[key]
        if isinstance(v, bool) or not isinstance(v, int | float) or not v > 0:
            raise ModelParameterError(f"scene needle_liver: {key} = {v!r} must be a number > 0")
        out[key] = float(v)
    for key in ("center_jitter_mm", "approach_max_deg"):
        v = out[key]
        if isinstance(v, bool) or not isinstance(v, int | float) or not 0 <= v:
            raise ModelParameterError(f"scene needle_liver: {key} = {v!r} must be a number ≥ 0")
        out[key] = float(v)
    if out["approach_max_deg"] > 80:
        raise ModelParameterError(
            f"scene needle_liver: approach_max_deg = {out['approach_max_deg']:g} must be ≤ 80 (from above)"
        )
    if out["tumour_diameter_mm"] >= out["liver_radius_mm"]:
        raise ModelParameterError("scene needle_liver: tumour_diameter_mm must be smaller than liver_radius_mm")
    seed = out["site_seed"]
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ModelParameterError(f"scene needle_liver: site_seed = {seed!r} must be an integer ≥ 0")
    size = out["view_size_px"]
    if isinstance(size, bool) or not isinstance(size, int) or not 32 <= size <= 2048:
        raise ModelParameterError(f"scene needle_liver: view_size_px = {size!r} must be an integer in 32…2048")
    out["center_mm"] = _vec3(out["center_mm"], "center_mm")
    out["view_center_mm"] = _vec3(out["view_center_mm"], "view_center_mm")
    return out


class NeedleLiverScene(Scene):
    """Nested-sphere liver with a tumour at the core, an incision point and a planned straight path.

    Parts (``needs``): ``layers`` — the sphere geometry a needle controller renders forces from (always
    cheap, built whenever the scene exists); ``view`` — the CT-like slice renderer and its textured
    background, built only when the condition shows images (scans on request or real time).
    """

    name = "needle_liver"
    PARAMS = PARAMS
    # protocol check: every refused value at its key, and the rules between them
    param_problems = problems_with_rules(PARAMS, _spec, "scene needle_liver: ")

    def __init__(self, spec: dict[str, Any], placement: Mapping[str, Any], needs: frozenset[str]) -> None:
        self.spec = spec
        self.placement = dict(placement)
        self.parts = frozenset(needs)
        c = _vec3(placement["tumour_center_mm"], "placement.tumour_center_mm")
        n = _vec3(placement["approach_dir"], "placement.approach_dir")
        norm = math.sqrt(sum(v * v for v in n))
        if norm < 1e-9:
            raise ModelParameterError("scene needle_liver: placement.approach_dir must be a non-zero vector")
        n = (n[0] / norm, n[1] / norm, n[2] / norm)
        r = spec["liver_radius_mm"]
        incision = (c[0] + r * n[0], c[1] + r * n[1], c[2] + r * n[2])
        self._geometry = NeedleGeometry(
            liver_center_mm=c,
            liver_radius_mm=r,
            tumour_center_mm=c,
            tumour_radius_mm=spec["tumour_diameter_mm"] / 2.0,
            incision_mm=incision,
        )
        self._renderer: _SliceRenderer | None = None
        if "view" in self.parts:
            seed = int(placement.get("texture_seed", 0))
            self._renderer = _SliceRenderer(self._geometry, spec, np.random.default_rng(seed))

    # ------------------------------------------------------------------ construction
    @classmethod
    def place(cls, spec: Mapping[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        """Draw one trial's placement: tumour centroid, incision direction and CT texture seed.

        The result is plain JSON data meant to be stored with the schedule so the trial can be rebuilt.
        """
        s = _spec(spec)
        j = s["center_jitter_mm"]
        c = [s["center_mm"][i] + float(rng.uniform(-j, j)) for i in range(3)]
        # uniform over the spherical cap of half-angle approach_max_deg about +z
        cos_max = math.cos(math.radians(s["approach_max_deg"]))
        cos_t = float(rng.uniform(cos_max, 1.0))
        phi = float(rng.uniform(0.0, 2.0 * math.pi))
        sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
        n = [sin_t * math.cos(phi), sin_t * math.sin(phi), cos_t]
        return {
            "tumour_center_mm": [round(v, 6) for v in c],
            "approach_dir": [round(v, 9) for v in n],
            "texture_seed": int(rng.integers(0, 2**31 - 1)),
        }

    @classmethod
    def site(cls, spec: Mapping[str, Any], k: int) -> dict[str, Any]:
        """Configuration number ``k`` (1-based) of the protocol's placement sites, the same every time.

        A protocol with ``scene.placement: {items: [tumour], sites: N}`` lets the schedule pick one of N
        fixed tumour/incision configurations per trial; the stored plan then says which one it was.
        """
        s = _spec(spec)
        if isinstance(k, bool) or not isinstance(k, int) or k < 1:
            raise ModelParameterError(f"scene needle_liver: placement site {k!r} must be an integer ≥ 1")
        return cls.place(spec, np.random.default_rng([s["site_seed"], k]))

    @classmethod
    def build(
        cls, spec: Mapping[str, Any], placement: Mapping[str, Any], needs: frozenset[str], rng: np.random.Generator
    ) -> NeedleLiverScene:
        """Build from the protocol's scene spec and this trial's stored placement.

        ``placement`` is either explicit (``tumour_center_mm``, ``approach_dir``, from :meth:`place`), or the
        schedule's ``{"sites": {"tumour": k}}`` (configuration k, see :meth:`site`), or empty: then one is
        drawn from ``rng`` (the trial's seeded scene stream).
        """
        s = _spec(spec)
        if "tumour_center_mm" in placement or "approach_dir" in placement:
            for key in ("tumour_center_mm", "approach_dir"):
                if key not in placement:
                    raise ModelParameterError(
                        f"scene needle_liver: placement lacks {key!r}; placements come from NeedleLiverScene.place"
                    )
            chosen = dict(placement)
        else:
            sites = placement.get("sites") or {}
            if sites:
                k = sites.get("tumour", next(iter(sites.values())))
                chosen = {**cls.site(spec, k), "site": k}
            else:
                chosen = cls.place(spec, rng)
        return cls(s, chosen, frozenset(needs))

    # ------------------------------------------------------------------ interface
    def geometry(self) -> NeedleGeometry:
        """The layer spheres and the planned path (what a needle controller renders forces from)."""
        return self._geometry

    def sense(self, inputs: Channels) -> dict[str, float]:
        """No extra sensors: the needle forces come from the controller's tissue model."""
        return {}

    def view(self, inputs: Channels) -> CTFrame | None:
        """The CT-like slices for the needle pose in ``inputs`` (``x_mm``… and the needle axis), or None.

        The axis is taken from the controller's ``needle_dir_*`` channels (frozen while in tissue) when
        present, else from the pen's ``dir_*`` channels, else straight down.
        """
        if self._renderer is None:
            return None
        g = inputs.get
        tip = (float(g("x_mm", 0.0)), float(g("y_mm", 0.0)), float(g("z_mm", 0.0)))
        if "needle_dir_x" in inputs:
            axis = (float(inputs["needle_dir_x"]), float(inputs["needle_dir_y"]), float(inputs["needle_dir_z"]))
        elif "dir_x" in inputs:
            axis = (float(inputs["dir_x"]), float(inputs["dir_y"]), float(inputs["dir_z"]))
        else:
            axis = (0.0, 0.0, -1.0)
        return CTFrame(self._renderer, tip, axis)

    def truth(self) -> dict[str, Any]:
        """Hidden ground truth for metrics: tumour centroid and radius, incision point, liver sphere."""
        g = self._geometry
        return {
            "tumour_center_mm": list(g.tumour_center_mm),
            "tumour_radius_mm": g.tumour_radius_mm,
            "incision_mm": list(g.incision_mm),
            "liver_center_mm": list(g.liver_center_mm),
            "liver_radius_mm": g.liver_radius_mm,
            "planned_length_mm": g.planned_length_mm,
        }


class _SliceRenderer:
    """Draws the two slices. Backgrounds (texture, liver, tumour, marker) are drawn once per trial."""

    PANELS = (
        # name, in-plane (horizontal, vertical) axes, normal axis
        ("axial", 0, 1, 2),
        ("coronal", 0, 2, 1),
    )

    def __init__(self, g: NeedleGeometry, spec: Mapping[str, Any], rng: np.random.Generator) -> None:
        self.size = int(spec["view_size_px"])
        self.mm_per_px = float(spec["view_mm_per_px"])
        self.center = spec["view_center_mm"]
        self.needle_length = float(spec["needle_length_mm"])
        self.gap = 4
        size = self.size
        self.shape = (size, 2 * size + self.gap)
        bg = np.full(self.shape, AIR, dtype=np.uint8)
        self.panels: list[dict[str, Any]] = []
        rows, cols = np.mgrid[0:size, 0:size].astype(float)
        for k, (name, ih, iv, inorm) in enumerate(self.PANELS):
            col0 = k * (size + self.gap)
            slice_mm = g.tumour_center_mm[inorm]
            h_mm = self.center[ih] + (cols - size / 2 + 0.5) * self.mm_per_px
            v_mm = self.center[iv] - (rows - size / 2 + 0.5) * self.mm_per_px
            panel = np.full((size, size), float(AIR))
            lc = g.liver_center_mm
            d_plane = slice_mm - lc[inorm]
            r2 = g.liver_radius_mm**2 - d_plane**2
            if r2 > 0:
                rr = np.sqrt((h_mm - lc[ih]) ** 2 + (v_mm - lc[iv]) ** 2)
                r_cut = math.sqrt(r2)
                tex = rng.normal(LIVER_LEVEL, LIVER_NOISE, (size, size)).clip(
                    LIVER_LEVEL - 4 * LIVER_NOISE, LIVER_LEVEL + 4 * LIVER_NOISE
                )
                panel = np.where(rr <= r_cut, tex, panel)
                ring = np.abs(rr - r_cut) <= 0.6 * self.mm_per_px + 0.25
                panel[ring] = CAPSULE_LEVEL
            tc = g.tumour_center_mm
            t2 = g.tumour_radius_mm**2 - (slice_mm - tc[inorm]) ** 2
            if t2 > 0:
                tumour = (h_mm - tc[ih]) ** 2 + (v_mm - tc[iv]) ** 2 <= t2
                panel[tumour] = TUMOUR_LEVEL + rng.normal(0.0, 4.0, int(tumour.sum())).clip(-12, 12)
            # radio-opaque skin marker at the planned incision point (projected), a small plus sign
            mh, mv = self._to_px(g.incision_mm[ih], g.incision_mm[iv], ih, iv)
            for dr, dc in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)):
                r_, c_ = mv + dr, mh + dc
                if 0 <= r_ < size and 0 <= c_ < size:
                    panel[r_, c_] = MARKER_LEVEL
            bg[:, col0 : col0 + size] = np.rint(panel).astype(np.uint8)
            self.panels.append(
                {
                    "name": name,
                    "col0": col0,
                    "size_px": size,
                    "h_axis": "xyz"[ih],
                    "v_axis": "xyz"[iv],
                    "normal_axis": "xyz"[inorm],
                    "slice_mm": slice_mm,
                    "center_h_mm": self.center[ih],
                    "center_v_mm": self.center[iv],
                    "mm_per_px": self.mm_per_px,
                    "axes": (ih, iv),
                }
            )
        self.background = bg
        self.background.setflags(write=False)

    def _to_px(self, h: float, v: float, ih: int, iv: int) -> tuple[int, int]:
        """Column and row of in-plane coordinates (mm) for the panel whose centre axes are (ih, iv)."""
        col = (h - self.center[ih]) / self.mm_per_px + self.size / 2 - 0.5
        row = -(v - self.center[iv]) / self.mm_per_px + self.size / 2 - 0.5
        return int(round(col)), int(round(row))

    def render(self, tip: tuple[float, float, float], axis: tuple[float, float, float]) -> np.ndarray:
        img = self.background.copy()
        n = math.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2) or 1.0
        u = (axis[0] / n, axis[1] / n, axis[2] / n)
        size, mpp = self.size, self.mm_per_px
        steps = int(self.needle_length / (0.5 * mpp)) + 1
        s = np.linspace(0.0, self.needle_length, steps)
        for panel in self.panels:
            ih, iv = panel["axes"]
            h = tip[ih] - s * u[ih]
            v = tip[iv] - s * u[iv]
            cols = np.rint((h - self.center[ih]) / mpp + size / 2 - 0.5).astype(np.int64)
            rows = np.rint(-(v - self.center[iv]) / mpp + size / 2 - 0.5).astype(np.int64)
            ok = (cols >= 0) & (cols < size) & (rows >= 0) & (rows < size)
            img[rows[ok], cols[ok] + panel["col0"]] = NEEDLE_LEVEL
        return img


class CTFrame(Mapping[str, Any]):
    """One CT-like frame: ``image`` (uint8 H×W, rendered on first access), ``panels`` (pixel ↔ device mm
    mapping of each slice), ``kind`` = "ct", and the needle pose it shows (``tip_mm``, ``axis``)."""

    __slots__ = ("_renderer", "_tip", "_axis", "_image")
    _KEYS = ("kind", "image", "panels", "shape", "tip_mm", "axis")

    def __init__(self, renderer: _SliceRenderer, tip: tuple[float, float, float], axis: tuple[float, ...]) -> None:
        self._renderer = renderer
        self._tip = tip
        self._axis = axis
        self._image: np.ndarray | None = None

    def __getitem__(self, key: str) -> Any:
        if key == "image":
            if self._image is None:
                self._image = self._renderer.render(self._tip, self._axis)  # type: ignore[arg-type]
            return self._image
        if key == "kind":
            return "ct"
        if key == "panels":
            return [{k: v for k, v in p.items() if k != "axes"} for p in self._renderer.panels]
        if key == "shape":
            return self._renderer.shape
        if key == "tip_mm":
            return self._tip
        if key == "axis":
            return self._axis
        raise KeyError(key)

    def __iter__(self) -> Iterator[str]:
        return iter(self._KEYS)

    def __len__(self) -> int:
        return len(self._KEYS)


def pixel_to_mm(panel: Mapping[str, Any], col: float, row: float) -> tuple[float, float]:
    """In-plane device coordinates (mm along ``h_axis``, ``v_axis``) of a pixel of a panel (col within it)."""
    size, mpp = panel["size_px"], panel["mm_per_px"]
    h = panel["center_h_mm"] + (col - size / 2 + 0.5) * mpp
    v = panel["center_v_mm"] - (row - size / 2 + 0.5) * mpp
    return h, v
