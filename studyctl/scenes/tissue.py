"""A virtual tissue whose forces come from stiffness maps (seeds 002 and 003).

Frames: the *tissue frame* is the phantom's own (the stiffness map, the surface mesh and the nodules are
defined there, z up from the table); the *device frame* is where the probe moves. A trial's placement
rotates the tissue about the centre of its footprint by ``orientation_deg`` (seed 003 changes the block's
orientation between tests; the protocol's ``scene.orientation`` draws it and the schedule stores it).

Scene spec (the protocol's ``scene.params``; every field optional)
------------------------------------------------------------------
``phantom``            ``seed003_block`` (default), ``seed002_curved`` (synthetic approximations, see
                       :mod:`studyctl.models.synthetic_phantom`) or ``measured``.
``phantom_options``    keyword arguments for the synthetic generator (``tissue_kpa``, ``noise_n`` …).
``map_seed``           seed of the synthetic sensor noise (default 0): every trial of a study palpates the
                       *same* phantom, as in the papers; the orientation is what changes.
``stiffness_map``      (measured) path of an ``.npz`` map or a manifest (:func:`load_stiffness_map`).
``surface``            (measured) ``{flat: {x_mm: [x0, x1], y_mm: [y0, y1], height_mm: h}}``,
                       ``{heights: path.npz}`` (arrays ``xs_mm``, ``ys_mm``, ``heights_mm``) or
                       ``{point_cloud: path.npy}`` (an (n, 3) cloud reconstructed as in seed 002).
``nodules``            (measured) ground truth ``[{name, x_mm, y_mm, diameter_mm}, …]`` in the tissue frame.
                       File paths are used as given: absolute, or relative to the folder studyctl runs in.
``indenter_radius_mm`` the avatar sphere of the deformation view (default 5).
``view_grid_mm``       display-grid spacing of the deformation view (default 2).
``warm_depth_mm``      depth below the surface to which the depth index is pre-built (default: the deepest
                       map depth + 3 mm), so that no 1 kHz tick pays for building it.
``tell_nodule_count``  put the number of nodules into :meth:`public` (default false).

Parts (``needs``): ``stiffness_map`` and ``surface`` are always built (cheap, cached across trials);
``view`` (or ``deformation_view``) builds the deformation display, only when a condition shows one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError, NotFoundError
from studyctl.models.force_render import Placement
from studyctl.models.point_cloud import surface_from_point_cloud
from studyctl.models.pseudo_haptics import DeformationView
from studyctl.models.stiffness_map import StiffnessMap
from studyctl.models.stiffness_map_files import load_stiffness_map
from studyctl.models.surface_mesh import SurfaceMesh
from studyctl.models.synthetic_phantom import PHANTOMS, Nodule
from studyctl.plugins.interfaces import Channels, Scene
from studyctl.plugins.params import Param, problems_with_rules

PHANTOM_CHOICES = (*PHANTOMS, "measured")
#: The scene's parameters (the protocol's ``scene.params``; see the module docstring), checked by ``studyctl
#: protocol check`` with their line. ``object``: null or a value :func:`_check_spec` checks (paths, nested specs).
PARAMS = (
    Param("phantom", "seed003_block", choices=PHANTOM_CHOICES, kind=str,
          source="CHOSEN: the seed 003 block, the synthetic stand-in closest to a paper's printed numbers"),
    Param("phantom_options", {}, kind=dict, doc="keyword arguments of the synthetic generator",
          source="CHOSEN: the generator's own defaults"),
    Param("map_seed", 0, 0, None, kind=int, doc="seed of the synthetic sensor noise", source="CHOSEN"),
    Param("stiffness_map", None, kind=object, doc="(measured) an .npz map or a manifest", source="the study's files"),
    Param("surface", None, kind=object, doc="(measured) flat, heights or point_cloud", source="the study's files"),
    Param("nodules", None, kind=object, doc="(measured) ground truth in the tissue frame", source="the study's files"),
    Param("indenter_radius_mm", 5.0, 0.0, None, unit="mm", doc="the avatar sphere of the deformation view",
          source="CHOSEN: inside seed 003's 6-10 mm indenter diameters"),
    Param("view_grid_mm", 2.0, 0.0, None, unit="mm", doc="display-grid spacing of the deformation view",
          source="CHOSEN"),
    Param("warm_depth_mm", None, kind=object, unit="mm", doc="depth the depth index is pre-built to",
          source="CHOSEN: the deepest map depth + 3 mm"),
    Param("tell_nodule_count", False, kind=bool, doc="put the number of nodules into public()", source="CHOSEN"),
)
DEFAULT_SPEC: dict[str, Any] = {p.name: p.default for p in PARAMS}


def _number(value: Any, name: str, *, low: float = 0.0, strict: bool = True) -> float:
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or (value <= low if strict else value < low):
        op = ">" if strict else "≥"
        raise ModelParameterError(f"scene stiffness_tissue: {name} = {value!r} must be a number {op} {low:g}")
    return float(value)


def _check_spec(spec: Mapping[str, Any]) -> dict[str, Any]:
    unknown = sorted(set(spec) - set(DEFAULT_SPEC))
    if unknown:
        raise ModelParameterError(
            f"scene stiffness_tissue: unknown field(s) {', '.join(unknown)}; allowed: {', '.join(DEFAULT_SPEC)}"
        )
    out = {**DEFAULT_SPEC, **dict(spec)}
    if out["phantom"] not in PHANTOM_CHOICES:
        raise ModelParameterError(
            f"scene stiffness_tissue: phantom = {out['phantom']!r}; allowed: {', '.join(PHANTOM_CHOICES)}"
        )
    if not isinstance(out["phantom_options"], Mapping):
        raise ModelParameterError("scene stiffness_tissue: phantom_options must be a mapping of generator options")
    seed = out["map_seed"]
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ModelParameterError(f"scene stiffness_tissue: map_seed = {seed!r} must be an integer ≥ 0")
    out["indenter_radius_mm"] = _number(out["indenter_radius_mm"], "indenter_radius_mm")
    out["view_grid_mm"] = _number(out["view_grid_mm"], "view_grid_mm")
    if out["warm_depth_mm"] is not None:
        out["warm_depth_mm"] = _number(out["warm_depth_mm"], "warm_depth_mm", strict=False)
    if not isinstance(out["tell_nodule_count"], bool):
        raise ModelParameterError("scene stiffness_tissue: tell_nodule_count must be true or false")
    if out["phantom"] == "measured":
        for key in ("stiffness_map", "surface", "nodules"):
            if out[key] is None:
                raise ModelParameterError(
                    f"scene stiffness_tissue: phantom 'measured' needs field {key!r} (see the scene's documentation)"
                )
    else:
        for key in ("stiffness_map", "surface", "nodules"):
            if out[key] is not None:
                raise ModelParameterError(
                    f"scene stiffness_tissue: field {key!r} is only used with phantom: measured "
                    f"(phantom is {out['phantom']!r})"
                )
    return out


def _freeze(value: Any) -> Any:
    if isinstance(value, Mapping):
        return tuple(sorted((k, _freeze(v)) for k, v in value.items()))
    if isinstance(value, list | tuple):
        return tuple(_freeze(v) for v in value)
    return value


class _Tissue:
    """The immutable models of one phantom: map, mesh (with its warmed index) and nodules."""

    def __init__(self, smap: StiffnessMap, mesh: SurfaceMesh, nodules: tuple[Nodule, ...], name: str) -> None:
        self.map = smap
        self.mesh = mesh
        self.nodules = nodules
        self.name = name


@lru_cache(maxsize=4)
def _tissue(frozen_spec: tuple) -> _Tissue:
    spec = dict(frozen_spec)
    phantom = spec["phantom"]
    if phantom != "measured":
        options = dict(spec["phantom_options"])
        try:
            ph = PHANTOMS[phantom](np.random.default_rng(spec["map_seed"]), **options)
        except TypeError as exc:
            raise ModelParameterError(f"scene stiffness_tissue: phantom_options for {phantom!r}: {exc}") from None
        mesh = SurfaceMesh.from_height_grid(ph.surface_xs_mm, ph.surface_ys_mm, ph.surface_heights_mm, source=phantom)
        smap, nodules = ph.stiffness, ph.nodules
    else:
        smap = load_stiffness_map(str(spec["stiffness_map"]))
        mesh = _measured_surface(dict(spec["surface"]), spec["map_seed"])
        nodules = _measured_nodules(spec["nodules"])
    warm = spec["warm_depth_mm"]
    mesh.warm(float(smap.depths_mm[-1]) + 3.0 if warm is None else float(warm))
    return _Tissue(smap, mesh, nodules, phantom)


def _measured_surface(surface: dict[str, Any], seed: int) -> SurfaceMesh:
    if len(surface) != 1 or next(iter(surface)) not in ("flat", "heights", "point_cloud"):
        raise ModelParameterError(
            "scene stiffness_tissue: surface must be exactly one of {flat: {...}}, {heights: file.npz}, "
            "{point_cloud: file.npy}"
        )
    kind, value = next(iter(surface.items()))
    if kind == "flat":
        flat = dict(value)
        try:
            xs = [float(v) for v in flat["x_mm"]]
            ys = [float(v) for v in flat["y_mm"]]
            h = float(flat["height_mm"])
        except (KeyError, TypeError, ValueError):
            raise ModelParameterError(
                "scene stiffness_tissue: surface.flat needs x_mm: [x0, x1], y_mm: [y0, y1], height_mm: h"
            ) from None
        return SurfaceMesh.from_height_grid(xs, ys, np.full((len(xs), len(ys)), h), source="surface.flat")
    path = Path(str(value))
    if not path.is_file():
        raise NotFoundError(f"scene stiffness_tissue: surface.{kind} file {path} does not exist")
    if kind == "heights":
        try:
            with np.load(path, allow_pickle=False) as data:
                return SurfaceMesh.from_height_grid(data["xs_mm"], data["ys_mm"], data["heights_mm"], source=str(path))
        except KeyError as exc:
            raise ModelParameterError(
                f"surface {path}: field {exc.args[0]!r} is missing; the .npz needs xs_mm, ys_mm, heights_mm"
            ) from None
    try:
        cloud = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ModelParameterError(f"surface {path}: not a readable .npy point cloud ({exc})") from None
    return surface_from_point_cloud(cloud, np.random.default_rng(seed)).mesh


def _measured_nodules(rows: Any) -> tuple[Nodule, ...]:
    if not isinstance(rows, list | tuple) or not rows:
        raise ModelParameterError("scene stiffness_tissue: nodules must be a non-empty list of {name, x_mm, y_mm, …}")
    out = []
    for k, row in enumerate(rows):
        if isinstance(row, tuple):  # a spec frozen for the cache
            row = dict(row)
        try:
            out.append(
                Nodule(
                    str(row.get("name", chr(ord("A") + k))),
                    float(row["x_mm"]),
                    float(row["y_mm"]),
                    float(row.get("diameter_mm", 0.0)),
                    float(row.get("top_depth_mm", 0.0)),
                    float(row.get("modulus_kpa", 0.0)),
                )
            )
        except (KeyError, TypeError, ValueError, AttributeError):
            raise ModelParameterError(
                f"scene stiffness_tissue: nodules[{k}] = {row!r} needs numbers x_mm and y_mm (and optionally name, "
                "diameter_mm)"
            ) from None
    return tuple(out)


_NONE: Mapping[str, Any] = {}
_MISSING = object()


def _pick(key: str, a: Channels, b: Channels, c: Channels) -> Any:
    """``{**a, **b, **c}.get(key, _MISSING)`` without building the merged dict."""
    if key in c:
        return c[key]
    if key in b:
        return b[key]
    return a[key] if key in a else _MISSING


class StiffnessTissueScene(Scene):
    """A stiffness-map tissue on a table, placed in the device frame by the trial's orientation.

    Controllers read :attr:`stiffness`, :attr:`mesh` and :attr:`placement` (tissue → device frame) and
    publish the avatar they render through their ``diagnostics`` channels (``cursor_x_mm`` …,
    ``tissue_depth_mm``, ``contact_x_mm``/``contact_y_mm`` in the tissue frame), which the trial loop hands to
    :meth:`view`. See the module docstring for the spec fields.
    """

    name = "stiffness_tissue"
    PARAMS = PARAMS
    # protocol check: every refused value at its key, and the rules between them
    param_problems = problems_with_rules(PARAMS, _check_spec, "scene stiffness_tissue: ")

    def __init__(self, spec: dict[str, Any], placement: Mapping[str, Any], needs: frozenset[str]) -> None:
        self.spec = spec
        self.parts = frozenset(needs)
        tissue = _tissue(_freeze(spec))
        self.stiffness: StiffnessMap = tissue.map
        self.mesh: SurfaceMesh = tissue.mesh
        self.nodules_local = tissue.nodules
        orientation = placement.get("orientation_deg")
        orientation = 0.0 if orientation is None else _number(orientation, "placement.orientation_deg", low=-1e9)
        x0, x1, y0, y1 = self.mesh.footprint_mm
        self.placement = Placement(float(orientation), ((x0 + x1) / 2.0, (y0 + y1) / 2.0), (0.0, 0.0, 0.0))
        self.deformation: DeformationView | None = None
        self._display: dict[str, Any] | None = None
        if self.parts & {"view", "deformation_view"}:
            g = spec["view_grid_mm"]
            xs = np.arange(x0, x1 + 0.5 * g, g)
            ys = np.arange(y0, y1 + 0.5 * g, g)
            self.deformation = DeformationView(xs, ys, spec["indenter_radius_mm"])
            heights = [[self.mesh.height_at(float(x), float(y)) for y in ys] for x in xs]
            # What a display needs to draw the deformation: the grid the node indices refer to (tissue
            # frame) and how the tissue sits in the device frame. Built once, shared by every frame.
            self._display = {
                "xs_mm": xs.tolist(),
                "ys_mm": ys.tolist(),
                "heights_mm": heights,
                "orientation_deg": self.placement.rotation_deg,
                "center_mm": list(self.placement.center_mm),
                "indenter_radius_mm": spec["indenter_radius_mm"],
            }
        self._surface_world = self._visible_surface()

    @classmethod
    def build(
        cls, spec: Mapping[str, Any], placement: Mapping[str, Any], needs: frozenset[str], rng: np.random.Generator
    ) -> StiffnessTissueScene:
        return cls(_check_spec(spec), placement or {}, needs)

    # ------------------------------------------------------------------ what others see
    def _visible_surface(self) -> dict[str, Any]:
        """The tissue's surface in the device frame on a 2 mm grid (NaN off the tissue): it is on screen."""
        x0, x1, y0, y1 = self.mesh.footprint_mm
        corners = [self.placement.to_world(x, y) for x in (x0, x1) for y in (y0, y1)]
        wx0, wx1 = min(c[0] for c in corners), max(c[0] for c in corners)
        wy0, wy1 = min(c[1] for c in corners), max(c[1] for c in corners)
        step = 2.0
        xs = np.arange(wx0, wx1 + 0.5 * step, step)
        ys = np.arange(wy0, wy1 + 0.5 * step, step)
        heights = np.full((xs.size, ys.size), np.nan)
        for i, x in enumerate(xs):
            for j, y in enumerate(ys):
                lx, ly, _ = self.placement.to_local(float(x), float(y))
                h = self.mesh.height_at(lx, ly)
                if h is not None:
                    heights[i, j] = h
        return {"xs_mm": xs.tolist(), "ys_mm": ys.tolist(), "heights_mm": heights.tolist()}

    def public(self) -> Mapping[str, Any]:
        """The visible tissue surface (device frame), a start pose above it and, if the spec says so, the
        number of nodules. Never the nodules' positions."""
        x0, x1, y0, y1 = self.mesh.footprint_mm
        cx, cy, _ = self.placement.to_world((x0 + x1) / 2.0, (y0 + y1) / 2.0)
        top = float(np.nanmax(self.mesh.heights_mm))
        out: dict[str, Any] = {"surface": self._surface_world, "start_mm": [cx, cy, top + 20.0]}
        if self.spec["tell_nodule_count"]:
            out["nodule_count"] = len(self.nodules_local)
        return out

    def marks(self) -> tuple[dict[str, Any], ...]:
        """The nodules as seen on a practice block (seed 003: "practice run with visible hard nodules"): name,
        centre (device frame) and diameter. The engine shows them only in practice, never in a test trial."""
        return tuple(dict(row) for row in self.truth()["nodules"])

    def truth(self) -> Mapping[str, Any]:
        """Nodule centres in the device frame (for metrics only)."""
        rows = []
        for n in self.nodules_local:
            x, y, _ = self.placement.to_world(n.x_mm, n.y_mm)
            rows.append({"name": n.name, "x_mm": x, "y_mm": y, "diameter_mm": n.diameter_mm})
        return {"nodules": rows, "orientation_deg": self.placement.rotation_deg}

    def sense(self, inputs: Channels) -> dict[str, float]:
        """Nothing beyond the device's own position channels: the controller computes depth and forces."""
        return {}

    def view(self, inputs: Channels) -> Mapping[str, Any] | None:
        """What the screen shows, every tick, at almost no cost.

        ``surface`` (device frame, 2 mm grid, NaN off the tissue) and ``cursor_mm`` (the avatar, device
        frame) always; ``depth_mm`` when the avatar is known. With the deformation display built:
        ``display`` (the display grid in the tissue frame with its heights, ``orientation_deg`` and
        ``center_mm`` of the placement) and, in contact, ``deformation``: a
        :class:`~studyctl.models.pseudo_haptics.PendingDeformation` whose ``compute()`` gives the displaced
        display nodes ``(i, j, dz_mm)`` (``to_dict()`` for JSON). Nothing is computed until drawn."""
        return self.view_parts(inputs, _NONE, _NONE)

    def view_parts(self, a: Channels, b: Channels, c: Channels) -> Mapping[str, Any] | None:
        """``view({**a, **b, **c})`` without merging the three mappings: the trial loop's real-time view asks
        this every tick with the participant's inputs, the device's observation and the controller's
        diagnostics (a channel in a later mapping wins, as in the merged dict)."""
        # The tissue controllers publish the avatar and depth in c (the last mapping, which wins): read them
        # straight, five dict lookups instead of four _pick calls a tick; the general path below otherwise.
        if "cursor_x_mm" in c and "cursor_y_mm" in c and "cursor_z_mm" in c and "tissue_depth_mm" in c:
            cx, cy, cz, depth = c["cursor_x_mm"], c["cursor_y_mm"], c["cursor_z_mm"], c["tissue_depth_mm"]
            if cx is not None and cy is not None and cz is not None:
                return self._frame(cx, cy, cz, float(depth), a, b, c)
        cx = _pick("cursor_x_mm", a, b, c)
        if cx is _MISSING:
            cx = _pick("x_mm", a, b, c)
        cy = _pick("cursor_y_mm", a, b, c)
        if cy is _MISSING:
            cy = _pick("y_mm", a, b, c)
        cz = _pick("cursor_z_mm", a, b, c)
        if cz is _MISSING:
            cz = _pick("z_mm", a, b, c)
        if cx is None or cy is None or cz is None or cx is _MISSING or cy is _MISSING or cz is _MISSING:
            return {"surface": self._surface_world, "cursor_mm": None}
        depth = _pick("tissue_depth_mm", a, b, c)
        return self._frame(cx, cy, cz, float(0.0 if depth is _MISSING else depth), a, b, c)

    def _frame(self, cx: Any, cy: Any, cz: Any, depth: float, a: Channels, b: Channels, c: Channels) -> dict[str, Any]:
        """The view of an avatar at (cx, cy, cz), ``depth`` into the tissue (see :meth:`view`)."""
        frame: dict[str, Any] = {
            "surface": self._surface_world,
            "cursor_mm": (float(cx), float(cy), float(cz)),
            "depth_mm": depth,
        }
        if self._display is not None:
            frame["display"] = self._display
        if self.deformation is not None and depth > 0.0:
            qx = _pick("contact_x_mm", a, b, c)
            qy = _pick("contact_y_mm", a, b, c)
            if qx is None or qy is None or qx is _MISSING or qy is _MISSING:
                qx, qy, _ = self.placement.to_local(float(cx), float(cy))
            frame["deformation"] = self.deformation.pending(float(qx), float(qy), depth)
        return frame
