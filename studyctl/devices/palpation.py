"""Simulated palpation hardware: the sensorised forceps in a scene, the balloon and the vibration motor.

Reading asks the scene for the force on the probe at the participant's current probe pose, passes it
through the force sensor and its 10-bit ADC (noise and quantisation; :mod:`studyctl.models.palpation_hw`)
and reports the calibrated force. Writing sets the actuators' control amounts; :meth:`feedback` gives what
they deliver (balloon pressure, vibration frequency and acceleration) after their dynamics.

Channels
--------
read: ``adc`` (counts), ``force_n`` (calibrated), ``pressure_kpa`` (over the sensing area), and the probe
pose ``probe_x_mm``, ``probe_y_mm``, ``depth_mm`` (simulation only; for contact metrics and the camera view).

The instrument is not rigid: the forceps' cable-driven wrist yields under load
(``instrument_compliance_mm_per_n``), so the tip sinks less far into the sponge than the surgeon's hand
commands, and less where a stiffer tumour pushes back. ``depth_mm`` is where the tip really is (what the
endoscope shows); with the sponge's force linear in depth the tip depth is ``d_cmd / (1 + c·K)``, K the
local stiffness. That difference is the only stiffness cue a person has without haptic feedback.
write: ``balloon_pct``, ``vibration_pct`` (0-100).
feedback: ``balloon_psi``, ``vibration_hz``, ``vibration_ms2``.

Faults can be injected for rehearsals and tests (``faults: [{kind, start_s, end_s}]``, kind ``stale``,
``adc_out_of_range`` or ``nan``); the safety layer must then hold the safe state.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from studyctl.devices.base import ParamDevice
from studyctl.errors import DeviceError, ModelParameterError
from studyctl.models.palpation_hw import A201, BalloonModel, VibrationMotorModel, count_in_table
from studyctl.plugins.interfaces import ChannelLimit, Channels, DeviceLimits, Observation
from studyctl.plugins.params import Param
from studyctl.scenes.sponge import SpongePhantomScene

FAULT_KINDS = ("stale", "adc_out_of_range", "nan")
NOISE_BLOCK = 512  # sensor-noise draws per block (~10 s of a 50 Hz loop, ~2 s at 250 Hz)


BALLOON_CEILING_PSI = 20.0  # seed 000: "maximum pressure ... set to 20 PSI"


def palpation_limits(ramp_up_s: float = 0.2, sensor_stale_s: float = 0.1,
                     max_balloon_psi: float = BALLOON_CEILING_PSI) -> DeviceLimits:
    """Output limits of the palpation driver board: control amounts 0-100, safe value 0 (both off).

    The balloon's pressure ceiling is a safety limit, not only the regulator's physics: ``balloon_pct`` is
    capped at the control amount that gives ``max_balloon_psi`` on the balloon's static curve (seed 000:
    20 psi, reached at 116, so the paper's 0-100 range is unchanged; a lower ceiling, e.g. for a pilot with
    sensitive fingers, lowers the cap). No rate limit: the valve array and the motor driver switch within a
    50 Hz tick (the piecewise controller's steps are part of the design).
    """
    if not (0.0 < max_balloon_psi <= BALLOON_CEILING_PSI):
        raise ModelParameterError(f"max_balloon_psi must be in (0, {BALLOON_CEILING_PSI:g}] psi (the regulator's "
                                  f"ceiling), got {max_balloon_psi!r}")
    balloon = BalloonModel()
    high = min(100.0, balloon.dead_zone + max_balloon_psi / balloon.slope_psi)
    return DeviceLimits(
        outputs=(
            ChannelLimit("balloon_pct", 0.0, high, safe=0.0, unit="%"),
            ChannelLimit("vibration_pct", 0.0, 100.0, safe=0.0, unit="%"),
        ),
        sensor_stale_s=sensor_stale_s,
        ramp_up_s=ramp_up_s,
    )


class SimulatedPalpationDevice(ParamDevice):
    """Simulated force-sensing forceps with pneumatic balloon and vibration motor (seed 000 hardware)."""

    name = "sim_palpation"
    simulated = True
    PARAMS = (
        Param("sensor_noise_lsb", 0.5, 0.0, 50.0, unit="LSB", source="CHOSEN: ADC noise before quantisation"),
        Param("ramp_up_s", 0.2, 0.0, 5.0, unit="s", source="CHOSEN: output ramp after enable"),
        Param("sensor_stale_s", 0.1, 0.001, 10.0, unit="s", source="CHOSEN: 5 missed 50 Hz samples"),
        Param("balloon_tau_s", BalloonModel.tau_s, 0.0, 5.0, unit="s", source="see BalloonModel"),
        Param("motor_tau_s", VibrationMotorModel.tau_s, 0.0, 5.0, unit="s", source="see VibrationMotorModel"),
        Param("max_balloon_psi", BALLOON_CEILING_PSI, 0.1, BALLOON_CEILING_PSI, unit="psi",
              source="CITED: seed 000, balloon regulator set to 20 psi; a safety limit (palpation_limits)"),
        Param("faults", (), kind=tuple, source="studyctl: fault injection for tests and rehearsals"),
        Param("instrument_compliance_mm_per_n", 0.5, 0.0, 10.0, unit="mm/N",
              source="CHOSEN: cable-driven EndoWrist forceps holding the sensor, ~2 N/mm at the tip (no source "
                     "gives it); the visible yield is the no-feedback stiffness cue"),
    )

    def setup(self, checked: dict[str, Any]) -> None:
        self.rng = self.rng if self.rng is not None else np.random.default_rng(0)
        self.limits = palpation_limits(checked["ramp_up_s"], checked["sensor_stale_s"], checked["max_balloon_psi"])
        self.sensor = A201
        self.balloon = BalloonModel(tau_s=checked["balloon_tau_s"])
        self.motor = VibrationMotorModel(tau_s=checked["motor_tau_s"])
        self.faults = tuple(_check_fault(f) for f in checked["faults"])
        self._open = False
        self._inputs: dict[str, float] = {}
        # Per-tick constants (read() runs every tick): the sensor's inverse table and area, the scene's force
        # function, and the actuators' lags. The same numbers the model methods compute, computed once.
        self._table = self.sensor.count_table()
        self._area_m2 = self.sensor.sensing_area_m2()
        self._adc_max = self.sensor.adc_max
        self._force_at = scene_force_function(self.scene) if self.scene is not None else None
        self._noise = checked["sensor_noise_lsb"]
        self._compliance = checked["instrument_compliance_mm_per_n"]
        # The sensor noise's standard normals, drawn from self.rng in blocks: a block holds the same numbers, in the
        # same order, as one draw a tick (the device owns its stream), and a scalar draw costs ~1.5 µs, a tenth of
        # the device's tick.
        self._normals: list[float] = []
        self._normal_i = 0
        self._reset_state()

    def _reset_state(self) -> None:
        self._set_command({"balloon_pct": 0.0, "vibration_pct": 0.0})
        self._psi = 0.0
        self._speed = 0.0
        self._t = None
        # the lags' exp(-dt/tau) for the last tick length (a simulated loop repeats the same dt)
        self._dt = None
        self._decay = (1.0, 1.0)
        self._last_sample: tuple[float, dict[str, float]] | None = None
        self._motor_out: tuple[float, tuple[float, float]] | None = None  # (speed, motor.output(speed)) last given

    # -- Device --------------------------------------------------------------------------------------
    def open(self) -> None:
        self._reset_state()
        self._open = True

    def close(self) -> None:
        self._set_command({"balloon_pct": 0.0, "vibration_pct": 0.0})
        self._open = False

    def apply_input(self, inputs: Channels) -> None:
        self._inputs.update({k: float(v) for k, v in inputs.items()})

    def read(self, t: float) -> Observation:
        if not self._open:
            raise DeviceError("sim_palpation device: read before open(); the engine must open the device first")
        self._advance(t)
        fault = self._fault_at(t) if self.faults else None
        if fault == "stale" and self._last_sample is not None:
            sample_t, values = self._last_sample
            return Observation(t, values, sample_t=sample_t)
        inputs = self._inputs
        x, y, depth = inputs.get("x_mm", -1.0), inputs.get("y_mm", -1.0), inputs.get("depth_mm", 0.0)
        force = 0.0
        force_at = self._force_at
        if force_at is not None:
            depth, force = contact(force_at, x, y, depth, self._compliance)
        sensor = self.sensor
        adc_max = self._adc_max
        counts = count_in_table(self._table, force, adc_max)
        noise = self._noise
        if noise > 0:
            i = self._normal_i
            if i >= len(self._normals):
                self._normals = self.rng.standard_normal(NOISE_BLOCK).tolist()
                i = 0
            self._normal_i = i + 1
            counts = int(min(max(round(counts + noise * self._normals[i]), 0), adc_max))
        faults: tuple[str, ...] = ()
        if fault == "adc_out_of_range":
            counts = adc_max + 77  # what a glitching board might send
        if 0 <= counts <= adc_max:
            force_n = sensor.force_of_count(counts)
        else:
            force_n = math.nan
            faults = (f"adc_out_of_range: {counts} not in 0..{adc_max}",)
        if fault == "nan":
            force_n = math.nan
        # the pressure as SensorCalibration.pressure_kpa computes it (by the area, then by 1e3)
        values = {"adc": float(counts), "force_n": force_n,
                  "pressure_kpa": force_n / self._area_m2 / 1e3 if math.isfinite(force_n) else math.nan,
                  "probe_x_mm": x, "probe_y_mm": y, "depth_mm": depth}
        self._last_sample = (t, values)
        return Observation(t, values, sample_t=t, faults=faults)

    def write(self, command: Channels) -> None:
        held = self._command
        changed = False
        for name in held:
            if name in command:
                value = float(command[name])
                # equal values give equal targets (each target subtracts a non-zero constant first, so ±0 agree)
                changed = changed or value != held[name]
                held[name] = value
        if changed:
            self._set_command(held)

    def feedback(self) -> dict[str, float]:
        # the motor's output is a function of its speed alone, which stays put for many ticks (off, or settled)
        speed = self._speed
        cached = self._motor_out
        if cached is None or cached[0] != speed:
            cached = self._motor_out = (speed, self.motor.output(speed))
        hz, ms2 = cached[1]
        return {"balloon_psi": self._psi, "vibration_hz": hz, "vibration_ms2": ms2}

    # -- internals -----------------------------------------------------------------------------------
    def _set_command(self, command: dict[str, float]) -> None:
        """Hold ``command`` and the actuators' static targets for it: a target depends on the command alone, and
        the command changes far less often than the loop ticks (read() steps the lags every tick)."""
        self._command = command
        self._targets = (self.balloon._target(command["balloon_pct"]), self.motor._target(command["vibration_pct"]))

    def _advance(self, t: float) -> None:
        """Run the actuator dynamics from the previous read to ``t`` under the last command."""
        last = self._t
        if last is not None and t > last:
            dt = t - last
            if dt != self._dt:
                self._dt = dt
                self._decay = (self.balloon.decay(dt), self.motor.decay(dt))
            decay_psi, decay_speed = self._decay
            target_psi, target_speed = self._targets
            # _FirstOrderActuator.step_decayed (models.palpation_hw.decayed_step) with the held targets, inline:
            # the same operations on the same numbers, without four calls a tick
            psi, speed = self._psi, self._speed
            self._psi = target_psi if decay_psi is None else target_psi + (psi - target_psi) * decay_psi
            self._speed = target_speed if decay_speed is None else target_speed + (speed - target_speed) * decay_speed
        self._t = t

    def _fault_at(self, t: float) -> str | None:
        for f in self.faults:
            if f["start_s"] <= t < f["end_s"]:
                return f["kind"]
        return None


def scene_force_function(scene: Any) -> Callable[[float, float, float], float]:
    """The scene's force (N) on the probe at (x, y, depth): the sponge's direct path (no dicts per tick), or
    its ``sense`` for any other scene."""
    if isinstance(scene, SpongePhantomScene):
        return scene.force_n

    def sensed(x: float, y: float, depth: float) -> float:
        return float(scene.sense({"x_mm": x, "y_mm": y, "depth_mm": depth}).get("force_n", 0.0))

    return sensed


def contact(force_at: Callable[[float, float, float], float], x: float, y: float, depth: float,
            compliance: float) -> tuple[float, float]:
    """(tip depth, force) of the forceps pressed to commanded ``depth`` mm at (x, y), the scene's force given by
    ``force_at``: the wrist yields until tip force and deflection agree, d = d_cmd − c·F(d) with F linear in d."""
    force = force_at(x, y, depth)
    if compliance > 0 and force > 0 and depth > 0:
        depth = depth / (1.0 + compliance * force / depth)
        force = force_at(x, y, depth)
    return depth, force


def forceps_contact(scene: Any, x: float, y: float, depth: float, compliance: float) -> tuple[float, float]:
    """:func:`contact` in ``scene``. Shared by the simulated device and the emulated world of a virtual rehearsal
    (:mod:`studyctl.devices.world`)."""
    return contact(scene_force_function(scene), x, y, depth, compliance)


def _check_fault(f: Any) -> dict[str, Any]:
    if not isinstance(f, Mapping) or f.get("kind") not in FAULT_KINDS:
        raise ModelParameterError(
            f"sim_palpation device: fault {f!r} must be a mapping with kind in {', '.join(FAULT_KINDS)}"
        )
    start, end = float(f.get("start_s", 0.0)), float(f.get("end_s", math.inf))
    if not end > start >= 0:
        raise ModelParameterError(f"sim_palpation device: fault {f!r} needs 0 ≤ start_s < end_s")
    return {"kind": f["kind"], "start_s": start, "end_s": end}
