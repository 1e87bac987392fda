"""Controllers of seeds 002 and 003: stiffness-map force feedback (FF), pseudo-haptic feedback (PHF) and
both together (PHF+FF), on a :class:`~studyctl.scenes.tissue.StiffnessTissueScene`.

All three run at 1 kHz, read the handle position (``x_mm``, ``y_mm``, ``z_mm``) and command ``fx_n``,
``fy_n``, ``fz_n``. They publish the avatar through ``diagnostics`` (logged with every sample and handed
to the scene's view): ``cursor_x_mm``/``cursor_y_mm``/``cursor_z_mm`` (device frame), ``tissue_depth_mm``,
``tissue_normal_n``/``tissue_horizontal_n`` (the table forces at the avatar), ``contact_x_mm``/
``contact_y_mm`` (tissue frame), ``ratio_n``/``ratio_h`` (the cursor/input ratios in force this tick).

Protocol parameters (``conditions[].params``), shared by the three unless noted
------------------------------------------------------------------------------
``max_force_n`` (3.3; PHANToM Omni peak, seeds 002/003), ``interpolation`` (``linear``; the papers'
look-up-table interpolation; also ``nearest``, ``cubic``, ``powerlaw``), ``subsample`` (1), ``outside``
(``zero``: no force off the mapped area; ``clamp``), ``release_on_retract`` (true; seed 003: no normal force
while the indentation depth decreases), ``retract_deadband_mm`` (0.02), ``horizontal`` (``oppose``;
``along``; ``off`` as in seed 002, which fed back the normal force only), ``min_motion_mm`` (0.05),
``workspace_scale`` (1.0: device mm → tissue mm), ``workspace_offset_mm`` ([0, 0, 0]).
PHF and PHF+FF add ``r0`` (1.0, the default ratio R₀), ``resync_mm_per_s`` (10), ``delta_threshold_n`` (0) and
``lateral_ratio`` (``horizontal``: equation 3; ``normal``: Table 1),
see :class:`~studyctl.models.pseudo_haptics.PseudoHapticParams`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

from studyctl.errors import ModelParameterError
from studyctl.models.force_lookup import INTERPOLATIONS
from studyctl.models.force_render import ForceRenderer, RenderParams
from studyctl.models.pseudo_haptics import LATERAL_RATIOS, PseudoHapticCursor, PseudoHapticParams
from studyctl.plugins.interfaces import Controller, Observation, Scene
from studyctl.plugins.params import Param, validate_params

RENDER_PARAMS = (
    Param("max_force_n", 3.3, low=0.01, high=50.0, unit="N", source="seeds 002/003: PHANToM Omni peak force"),
    Param(
        "interpolation", "linear", choices=INTERPOLATIONS, kind=str, source="seeds 002/003: linear look-up table"
    ),
    Param("subsample", 1, low=1, high=64, kind=int, source="chosen: full table"),
    Param("outside", "zero", choices=("zero", "clamp"), kind=str, source="chosen: safe force off the map"),
    Param("release_on_retract", True, kind=bool, source="seed 003 §2.5"),
    Param("retract_deadband_mm", 0.02, low=0.0, high=5.0, unit="mm", source="chosen: 2× encoder resolution"),
    Param("horizontal", "oppose", choices=("oppose", "along", "off"), kind=str, source="seed 003 eq. 4-5"),
    Param("min_motion_mm", 0.05, low=0.0, high=10.0, unit="mm", source="chosen: 5× encoder resolution"),
    Param("workspace_scale", 1.0, low=1e-3, high=1e3, source="chosen: device mm = tissue mm"),
    Param("workspace_offset_mm", (0.0, 0.0, 0.0), kind=list, unit="mm", source="chosen"),
)
PHF_PARAMS = (
    Param("r0", 1.0, low=1e-3, high=100.0, source="seed 003: default cursor/input ratio R0 (value not printed)"),
    Param("resync_mm_per_s", 10.0, low=0.0, high=1000.0, unit="mm/s", source="chosen, see pseudo_haptics"),
    Param("delta_threshold_n", 0.0, low=0.0, high=10.0, unit="N", source="seed 003 Table 1: Δf_n > 0"),
    Param("lateral_ratio", "horizontal", choices=LATERAL_RATIOS, kind=str,
          source="seed 003: horizontal = eq. 3 (R_h from f_h), normal = Table 1 (R_n for x, y too)"),
)


def _tissue_scene(owner: str, scene: Scene | None) -> Any:
    for attr in ("stiffness", "mesh", "placement"):
        if scene is None or not hasattr(scene, attr):
            raise ModelParameterError(
                f"controller {owner}: needs a stiffness_tissue scene (a scene with a stiffness map, a surface mesh "
                f"and a placement); got {type(scene).__name__ if scene is not None else 'no scene'}"
            )
    return scene


class _TissueController(Controller):
    rate_hz = 1000.0
    # The renderer is stateless between ticks apart from contact bookkeeping, and the pseudo-haptic cursor
    # integrates with the measured time step, so a simulated session may run these below 1 kHz.
    rate_adjustable = True
    outputs: ClassVar[tuple[str, ...]] = ("fx_n", "fy_n", "fz_n")
    PARAMS: ClassVar[tuple[Param, ...]] = RENDER_PARAMS

    def __init__(self, params: Mapping[str, Any], scene: Scene | None = None) -> None:
        super().__init__(params, scene)
        p = validate_params(f"{self.name} controller", params, self.PARAMS)
        offset = p["workspace_offset_mm"]
        if len(offset) != 3 or not all(isinstance(v, int | float) and math.isfinite(v) for v in offset):
            raise ModelParameterError(
                f"{self.name} controller: parameter 'workspace_offset_mm' = {list(offset)!r} must be [x, y, z] in mm"
            )
        self.params = p
        tissue = _tissue_scene(self.name, scene)
        render = RenderParams.from_mapping(p, where=f"{self.name} controller")
        self.renderer = ForceRenderer(tissue.stiffness, tissue.mesh, render, tissue.placement)
        self._k = float(p["workspace_scale"])
        self._off = tuple(float(v) for v in offset)
        # Non-empty from the start: the trial loop keeps a reference to this very dict.
        self.diagnostics: dict[str, float] = {
            "cursor_x_mm": 0.0,
            "cursor_y_mm": 0.0,
            "cursor_z_mm": 0.0,
            "tissue_depth_mm": 0.0,
            "tissue_normal_n": 0.0,
            "tissue_horizontal_n": 0.0,
            "contact_x_mm": 0.0,
            "contact_y_mm": 0.0,
            "ratio_n": 1.0,
            "ratio_h": 1.0,
        }

    @classmethod
    def needs(cls, params: Mapping[str, Any]) -> frozenset[str]:
        return frozenset({"stiffness_map", "surface"})

    def reset(self) -> None:
        self.renderer.reset()

    def _hand(self, obs: Observation) -> tuple[float, float, float]:
        v = obs.values
        k, o = self._k, self._off
        return (o[0] + k * v["x_mm"], o[1] + k * v["y_mm"], o[2] + k * v["z_mm"])

    def _publish(self, x: float, y: float, z: float, depth: float, rn: float, rh: float) -> None:
        d = self.diagnostics
        r = self.renderer
        d["cursor_x_mm"], d["cursor_y_mm"], d["cursor_z_mm"] = x, y, z
        d["tissue_depth_mm"] = depth
        d["tissue_normal_n"], d["tissue_horizontal_n"] = r.last_table_n, r.last_table_h
        d["contact_x_mm"], d["contact_y_mm"] = r.last_contact_xy
        d["ratio_n"], d["ratio_h"] = rn, rh


class StiffnessMapForceFeedback(_TissueController):
    """Force feedback from stiffness maps (seed 002 haptic condition; seed 003 FF): the avatar is the handle."""

    name = "stiffness_map_ff"

    def step(self, obs: Observation) -> dict[str, float]:
        x, y, z = self._hand(obs)
        fx, fy, fz, _fn, _fh, depth, _contact, _retract = self.renderer.render(x, y, z)
        self._publish(x, y, z, depth, 1.0, 1.0)
        return {"fx_n": fx, "fy_n": fy, "fz_n": fz}


class PseudoHaptic(_TissueController):
    """Pseudo-haptic feedback only (seed 003 PHF): the cursor moves by R·Δinput; the device renders no force."""

    name = "pseudo_haptic"
    PARAMS: ClassVar[tuple[Param, ...]] = RENDER_PARAMS + PHF_PARAMS
    _force_feedback = False

    def __init__(self, params: Mapping[str, Any], scene: Scene | None = None) -> None:
        super().__init__(params, scene)
        self.cursor = PseudoHapticCursor(PseudoHapticParams.from_mapping(self.params, where=f"{self.name} controller"))
        self._started = False
        self._t_prev = 0.0

    @classmethod
    def needs(cls, params: Mapping[str, Any]) -> frozenset[str]:
        return frozenset({"stiffness_map", "surface", "view"})  # the cursor on screen is the feedback

    def reset(self) -> None:
        super().reset()
        self._started = False
        self._t_prev = 0.0

    def step(self, obs: Observation) -> dict[str, float]:
        hand = self._hand(obs)
        r = self.renderer
        if not self._started:
            self.cursor.reset(hand)
            self._started = True
            self._t_prev = obs.t
            fx, fy, fz, _fn, _fh, depth, contact, _ = r.render(*hand)
        else:
            dt = max(obs.t - self._t_prev, 0.0)
            self._t_prev = obs.t
            # The ratios use the table forces at the cursor before this tick's move (last tick's render).
            in_contact = self.diagnostics["tissue_depth_mm"] > 0.0
            cx, cy, cz = self.cursor.step(hand, r.last_table_n, r.last_table_h, in_contact, dt)
            fx, fy, fz, _fn, _fh, depth, contact, _ = r.render(cx, cy, cz)
        if not contact:
            r.last_table_n = r.last_table_h = 0.0
        c = self.cursor.cursor
        self._publish(c[0], c[1], c[2], depth, self.cursor.last_ratio_n, self.cursor.last_ratio_h)
        if self._force_feedback:
            return {"fx_n": fx, "fy_n": fy, "fz_n": fz}
        return {"fx_n": 0.0, "fy_n": 0.0, "fz_n": 0.0}


class PseudoHapticForceFeedback(PseudoHaptic):
    """Pseudo-haptic and force feedback together (seed 003 PHF+FF): forces are rendered at the cursor."""

    name = "pseudo_haptic_ff"
    _force_feedback = True
