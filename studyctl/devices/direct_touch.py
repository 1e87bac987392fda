"""The bare finger on the real phantom: a simulated direct-touch "device" for virtual participants in the
manual conditions of seeds 002 and 003.

In a manual condition a person palpates the silicone phantom itself (under a cover that hides the nodules)
and nothing is instrumented; the coordinator enters what was found and the time. A virtual participant has
no phantom to touch, so the engine gives it this device over the trial's scene instead: the participant's
inputs (``x_mm``, ``y_mm``, ``z_mm``: where the hand puts the fingertip, device frame) move the fingertip,
and what it feels (:meth:`DirectTouchDevice.feedback`) is the tissue's own reaction force at the fingertip.

The reaction force is the same physical model the FF controller renders (:class:`~studyctl.models.
force_render.ForceRenderer` over the scene's stiffness map, surface mesh and placement: depth to the nearest
surface triangle, look-up-table interpolation, normal force along the contact normal, horizontal force
against the sliding motion), with what belongs to the haptic device taken out:

* no 3.3 N device clamp (``max_force_n`` is only a guard far above any palpation force; beyond the deepest
  measured depth the map holds its deepest force, so the force stays finite anyway);
* no "no normal force while retracting" rule: that is seed 003's rendering choice for the device; the
  real elastic phantom keeps pushing on a withdrawing finger;
* no pseudo-haptic cursor and no screen: the device has no view; the participant sees the covered phantom's
  surface (the scene's ``public()``), never the nodules;
* no actuators: nothing can be commanded (``limits`` has no output channels).

Simplifications (CHOSEN, stated so they can be revisited): the fingertip is kinematic (it is where the hand
puts it; the hand is far stiffer than the silicone) and a point contact on the map (the pulp's own
compliance and its contact area are not modelled; the map was measured with an indenter of similar size).
How finely the finger *perceives* the force is the participant's business (``studyctl.participants.
tissue_palpator``: a finer stiffness discrimination for direct touch), not the device's.

The feedback carries ``direct_touch = 1.0`` so a participant knows it is touching with its own finger (a
person knows that too).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from studyctl.devices.base import ParamDevice
from studyctl.errors import DeviceError, ModelParameterError
from studyctl.models.force_render import INTERPOLATIONS, ForceRenderer, RenderParams
from studyctl.plugins.interfaces import Channels, DeviceLimits, Observation, Scene
from studyctl.plugins.params import Param

PARAMS = (
    Param(
        "interpolation",
        "linear",
        choices=INTERPOLATIONS,
        kind=str,
        source="seeds 002/003: linear look-up table (the same model the FF controller renders)",
    ),
    Param(
        "horizontal",
        "oppose",
        choices=("oppose", "along", "off"),
        kind=str,
        source="chosen: the real tissue resists a sliding finger (seed 003 eq. 4-5 magnitude)",
    ),
    Param("outside", "zero", choices=("zero", "clamp"), kind=str, source="chosen: off the phantom there is no tissue"),
    Param(
        "max_force_n",
        100.0,
        low=1.0,
        high=1e4,
        unit="N",
        source="chosen: no device clamp; only a guard far above any palpation force",
    ),
    Param("min_motion_mm", 0.05, low=0.0, high=10.0, unit="mm", source="as the FF controller"),
)


def _tissue_scene(scene: Scene | None) -> Any:
    for attr in ("stiffness", "mesh", "placement"):
        if scene is None or not hasattr(scene, attr):
            raise ModelParameterError(
                "device direct_touch: needs a stiffness_tissue scene (a phantom with a stiffness map, a surface "
                f"mesh and a placement) to touch; got {type(scene).__name__ if scene is not None else 'no scene'}"
            )
    return scene


class DirectTouchDevice(ParamDevice):
    """A fingertip on the scene's phantom; ``params`` as in :data:`PARAMS`, ``scene`` a stiffness tissue.

    Observation channels: ``x_mm``/``y_mm``/``z_mm`` (fingertip, device frame), ``vx_mm_s``/``vy_mm_s``/
    ``vz_mm_s`` (finite difference over one tick), ``fx_n``/``fy_n``/``fz_n`` (the tissue's reaction on the
    fingertip, device frame), ``depth_mm`` (indentation), ``fault``.
    """

    name = "direct_touch"
    simulated = True
    PARAMS: ClassVar[tuple[Param, ...]] = PARAMS

    def setup(self, p: dict[str, Any]) -> None:
        tissue = _tissue_scene(self.scene)
        self.params = p
        render = RenderParams(
            max_force_n=float(p["max_force_n"]),
            interpolation=p["interpolation"],
            outside=p["outside"],
            release_on_retract=False,
            horizontal=p["horizontal"],
            min_motion_mm=float(p["min_motion_mm"]),
        )
        self.renderer = ForceRenderer(tissue.stiffness, tissue.mesh, render, tissue.placement)
        self.limits = DeviceLimits(outputs=(), max_force_n=None)  # a finger has no actuators
        self._opened = False
        self._reset_state()

    def _reset_state(self) -> None:
        self._tip: tuple[float, float, float] | None = None
        self._prev: tuple[float, float, float] | None = None
        self._t_prev: float | None = None
        self._feedback: dict[str, float] = {
            "fx_n": 0.0, "fy_n": 0.0, "fz_n": 0.0, "x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0, "direct_touch": 1.0,
        }
        self.renderer.reset()

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        self._reset_state()
        self._opened = True

    def close(self) -> None:
        self._opened = False

    # ------------------------------------------------------------------ the tick
    def apply_input(self, inputs: Channels) -> None:
        """Where the hand puts the fingertip (device frame, mm)."""
        if not self._opened:
            raise DeviceError("device direct_touch: apply_input before open()")
        x = inputs.get("x_mm")
        if x is None:
            return
        y, z = inputs.get("y_mm", 0.0), inputs.get("z_mm", 0.0)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise DeviceError(f"device direct_touch: non-finite fingertip position ({x}, {y}, {z})")
        self._tip = (float(x), float(y), float(z))

    def read(self, t: float) -> Observation:
        tip = self._tip
        fb = self._feedback
        if tip is None:  # the hand has not reached out yet: nothing touched
            return Observation(t, {"x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0, "vx_mm_s": 0.0, "vy_mm_s": 0.0,
                                   "vz_mm_s": 0.0, "fx_n": 0.0, "fy_n": 0.0, "fz_n": 0.0, "depth_mm": 0.0,
                                   "fault": 0.0})
        fx, fy, fz, _fn, _fh, depth, _contact, _retract = self.renderer.render(*tip)
        prev, tp = self._prev, self._t_prev
        if prev is None or tp is None or t <= tp:
            vx = vy = vz = 0.0
        else:
            inv = 1.0 / (t - tp)
            vx, vy, vz = (tip[0] - prev[0]) * inv, (tip[1] - prev[1]) * inv, (tip[2] - prev[2]) * inv
        self._prev, self._t_prev = tip, t
        fb["fx_n"], fb["fy_n"], fb["fz_n"] = fx, fy, fz
        fb["x_mm"], fb["y_mm"], fb["z_mm"] = tip
        return Observation(
            t,
            {
                "x_mm": tip[0], "y_mm": tip[1], "z_mm": tip[2], "vx_mm_s": vx, "vy_mm_s": vy, "vz_mm_s": vz,
                "fx_n": fx, "fy_n": fy, "fz_n": fz, "depth_mm": depth, "fault": 0.0,
            },
        )

    def write(self, command: Channels) -> None:
        """Nothing to actuate: the force on the finger is the tissue's, not commanded."""
        return None

    def feedback(self) -> dict[str, float]:
        """What the fingertip feels (the tissue's reaction, N) and where it is (mm, proprioception)."""
        return self._feedback
