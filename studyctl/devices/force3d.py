"""A simulated 3-DoF force-feedback device (PHANToM Omni or omega.6 class) with a simulated hand.

Inputs (from a virtual participant): ``x_mm``, ``y_mm``, ``z_mm`` — where the hand wants the handle —
and optionally the pen axis ``dir_x``/``dir_y``/``dir_z`` and a ``button`` (0/1), passed through, and ``grip_damping``:
how steadily the hand holds the handle, a factor on the hand's damping (1, the default, is the relaxed hold of
the parameters; a value persists until the next one is given).
Outputs (from the controller): ``fx_n``, ``fy_n``, ``fz_n`` in the device frame.

With ``hand = "spring"`` (default) the handle is a mass held by the hand through a spring-damper towards
the wanted position, and the rendered force acts on that mass: forces push the hand back, as on a real
device. ``hand = "none"`` puts the handle exactly where the inputs say (kinematic, for scripted probes).
The reported position is quantised to the encoder resolution and the velocity is a finite difference over
``velocity_window_s`` (the Force Dimension SDK's default estimator window is 20 ms), so the controller sees
realistic velocity noise. The force written in one tick acts during the next (zero-order hold).
When the control loop runs slower than ``rate_hz`` (a simulated session at a reduced loop rate), the
handle's dynamics and the encoder still run at ``rate_hz``, the last force held between loop ticks.

A reading that is not finite or jumps further than ``max_jump_mm`` in one tick puts the device in its
safe state: zero force from then on (latched), the reason in :attr:`fault` and in every observation's
``faults``, so the safety layer logs a ``device_fault`` and the trial loop ends the trial.
"""

from __future__ import annotations

import math
from typing import Any

from studyctl.devices.base import ParamDevice
from studyctl.errors import DeviceError
from studyctl.plugins.interfaces import ChannelLimit, Channels, DeviceLimits, Observation
from studyctl.plugins.params import Param

_ROUND = 6755399441055744.0  # 1.5 * 2**52

# Device classes: peak force (N), from the CHAI3D driver specs (see research/haptics.md).
DEVICE_CLASSES = {"omni": 3.3, "omega6": 12.0}


class SimulatedForceDevice(ParamDevice):
    """Simulated 3-DoF force device; parameters in :attr:`PARAMS`, ``scene`` optional.

    When a scene is given its :meth:`~studyctl.plugins.interfaces.Scene.sense` channels are added to every
    observation (palpation scenes report pressures or depths there).
    """

    name = "sim_force3d"
    simulated = True
    PARAMS = (
        Param("device_class", "omni", choices=tuple(DEVICE_CLASSES), kind=str,
              source="CHAI3D driver specs: omni 3.3 N, omega6 12 N peak"),
        Param("max_force_n", None, 1e-3, 50.0, unit="N", source="None: the device class's peak force"),
        Param("rate_hz", 1000.0, 1.0, 20000.0, unit="Hz", source="servo rate of haptic devices"),
        Param("hand", "spring", choices=("spring", "none"), kind=str,
              source="CHOSEN: spring = a hand holds the handle; none = kinematic probe"),
        Param("hand_mass_kg", 0.5, 1e-3, 10.0, unit="kg", source="CHOSEN: handle plus moving hand/forearm"),
        Param("hand_stiffness_n_per_m", 300.0, 0.0, 5000.0, unit="N/m", source="CHOSEN: relaxed grip 100–500 N/m"),
        Param("hand_damping_ns_per_m", 8.0, 0.0, 500.0, unit="N·s/m", source="CHOSEN: relaxed arm"),
        Param("resolution_mm", 0.01, 1e-6, 1.0, unit="mm", source="CHOSEN: encoder resolution of this class"),
        Param("velocity_window_s", 0.02, 1e-3, 1.0, unit="s", source="Force Dimension SDK default window"),
        Param("max_jump_mm", 5.0, 1e-3, 1000.0, unit="mm",
              source="CHOSEN: 5 mm in one 1 ms tick = 5 m/s, no hand moves like that"),
        Param("ramp_up_s", 0.0, 0.0, 10.0, unit="s", source="CHOSEN: no hardware to protect"),
        Param("max_force_rate_n_per_s", None, 1.0, 1e6, unit="N/s", source="None: no slew limit"),
    )  # fmt: skip

    def setup(self, p: dict[str, Any]) -> None:
        if p["max_force_n"] is None:
            p["max_force_n"] = DEVICE_CLASSES[p["device_class"]]
        self.params = p
        self.max_force_n = float(p["max_force_n"])
        self.rate_hz = float(p["rate_hz"])
        rate_limit = p["max_force_rate_n_per_s"]
        self.limits = DeviceLimits(
            outputs=tuple(
                ChannelLimit(ch, -self.max_force_n, self.max_force_n, 0.0, rate_limit, "N")
                for ch in ("fx_n", "fy_n", "fz_n")
            ),
            max_force_n=self.max_force_n,
            ramp_up_s=float(p["ramp_up_s"]),
        )
        self._dt = 1.0 / self.rate_hz
        self._kinematic = p["hand"] == "none"
        self._m = float(p["hand_mass_kg"])
        self._kh = float(p["hand_stiffness_n_per_m"])
        self._bh = float(p["hand_damping_ns_per_m"])
        self._res = float(p["resolution_mm"])
        self._inv_res = 1.0 / self._res
        self._win = max(1, round(float(p["velocity_window_s"]) * self.rate_hz))
        self._vel_scale = self.rate_hz / self._win  # 1 / the window's length in s (the ring holds _win samples)
        self._max_jump = float(p["max_jump_mm"])
        self._opened = False
        self._reset_state()

    def _reset_state(self) -> None:
        self._target: list[float] | None = None
        self._pos = [0.0, 0.0, 0.0]  # true handle position (mm)
        self._vel = [0.0, 0.0, 0.0]  # true handle velocity (mm/s)
        self._meas = (0.0, 0.0, 0.0)
        self._ring: list[tuple[float, float, float] | list[float]] = []  # readings, and positions (see _substeps)
        self._ring_i = 0
        self._force = [0.0, 0.0, 0.0]
        self._dir = (0.0, 0.0, -1.0)
        self._button = 1.0
        self._grip_b = 1.0
        self._t_last: float | None = None
        self.fault: str | None = None
        self.faults: list[dict[str, Any]] = []
        self._feedback = {"fx_n": 0.0, "fy_n": 0.0, "fz_n": 0.0, "x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0}

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        self._reset_state()
        self._opened = True

    def close(self) -> None:
        self._force = [0.0, 0.0, 0.0]
        self._feedback.update(fx_n=0.0, fy_n=0.0, fz_n=0.0)
        self._opened = False

    def _enter_safe_state(self, reason: str) -> None:
        if self.fault is None:
            self.fault = reason
            self.faults.append({"kind": "device_fault", "reason": reason})
        self._force = [0.0, 0.0, 0.0]
        self._feedback.update(fx_n=0.0, fy_n=0.0, fz_n=0.0)

    # ------------------------------------------------------------------ the tick
    def apply_input(self, inputs: Channels) -> None:
        """Take the hand's wanted position (and pen axis, button) from a virtual participant."""
        if not self._opened:
            raise DeviceError("device sim_force3d: apply_input before open()")
        x = inputs.get("x_mm")
        if x is not None:
            y, z = inputs.get("y_mm", 0.0), inputs.get("z_mm", 0.0)
            if x - x != 0.0 or y - y != 0.0 or z - z != 0.0:  # NaN or ±inf (x − x is NaN for both)
                self._enter_safe_state(f"non-finite input position ({x}, {y}, {z})")
                return
            if self._target is None:
                # the hand holds the handle at rest where it starts
                self._pos = [float(x), float(y), float(z)]  # type: ignore[arg-type]
                q = self._quantise(self._pos)
                self._meas = q
                self._ring = [q] * self._win
            # Python floats: a participant's numpy scalars would otherwise make every later tick's integration,
            # observation and controller step numpy-scalar arithmetic (same IEEE doubles, several times slower).
            self._target = [float(x), float(y), float(z)]  # type: ignore[arg-type]
        d = inputs.get("dir_x")
        if d is not None:
            self._dir = (d, inputs.get("dir_y", 0.0), inputs.get("dir_z", 0.0))
        b = inputs.get("button")
        if b is not None:
            self._button = b
        g = inputs.get("grip_damping")
        if g is not None:
            if not (g > 0.0 and g - g == 0.0):  # non-positive, NaN or ±inf
                self._enter_safe_state(f"grip_damping {g} is not a finite positive factor")
                return
            self._grip_b = float(g)

    def _substeps(self, n: int) -> None:
        """``n`` device ticks under the held force, the encoder sampled after each but the last (``read`` takes
        that one): :meth:`_integrate` unrolled, because a reduced-rate loop spends most of a read here.

        The ring keeps these samples' true positions (lists; readings are tuples) and ``read`` rounds one only if it
        takes it: at a steady reduced rate (4 device ticks a loop tick at 250 Hz, a 20-tick window) the window's
        oldest sample is always a reading, so rounding the others as they were taken was work never used."""
        if self._target is None or self._kinematic or not self._ring:
            for step in range(n):
                self._integrate(self._dt)
                if step < n - 1 and self._ring:
                    self._ring[self._ring_i] = list(self._pos)
                    self._ring_i = (self._ring_i + 1) % len(self._ring)
            return
        dt = self._dt
        g = dt * 1000.0 / self._m
        k = self._kh * 1e-3
        den = 1.0 + dt * self._bh * self._grip_b / self._m
        pos, vel = self._pos, self._vel
        p0, p1, p2 = pos
        v0, v1, v2 = vel
        f0, f1, f2 = self._force
        t0, t1, t2 = self._target
        ring, i, size = self._ring, self._ring_i, len(self._ring)
        for step in range(n):
            v0 = (v0 + g * (k * (t0 - p0) + f0)) / den
            v1 = (v1 + g * (k * (t1 - p1) + f1)) / den
            v2 = (v2 + g * (k * (t2 - p2) + f2)) / den
            p0 += dt * v0
            p1 += dt * v1
            p2 += dt * v2
            if step < n - 1:  # the position itself, a list: read rounds it if and when it is read
                ring[i] = [p0, p1, p2]
                i = 0 if i + 1 == size else i + 1
        pos[0], pos[1], pos[2] = p0, p1, p2
        vel[0], vel[1], vel[2] = v0, v1, v2
        self._ring_i = i

    def _quantise(self, p: list[float]) -> tuple[float, float, float]:
        """Encoder reading of a position (mm)."""
        r = self._res
        return (round(p[0] / r) * r, round(p[1] / r) * r, round(p[2] / r) * r)

    def _integrate(self, dt: float) -> None:
        """Semi-implicit Euler of the handle mass under the hand's spring-damper and the device force.

        The hand's damping is treated implicitly, so any hand damping is stable; positions in mm,
        velocities in mm/s, forces in N.
        """
        pos, vel, f, tgt = self._pos, self._vel, self._force, self._target
        if tgt is None:
            return
        if self._kinematic:
            for i in range(3):
                vel[i] = (tgt[i] - pos[i]) / dt
                pos[i] = tgt[i]
            return
        g = dt * 1000.0 / self._m  # N → mm/s per step
        k = self._kh * 1e-3  # N per mm
        den = 1.0 + dt * self._bh * self._grip_b / self._m
        v0 = (vel[0] + g * (k * (tgt[0] - pos[0]) + f[0])) / den
        v1 = (vel[1] + g * (k * (tgt[1] - pos[1]) + f[1])) / den
        v2 = (vel[2] + g * (k * (tgt[2] - pos[2]) + f[2])) / den
        vel[0], vel[1], vel[2] = v0, v1, v2
        pos[0] += dt * v0
        pos[1] += dt * v1
        pos[2] += dt * v2

    def read(self, t: float) -> Observation:
        last = self._t_last
        if last is not None:
            n = int((t - last) * self.rate_hz + 0.5)
            if n == 1:
                self._integrate(self._dt)
            else:
                # A loop slower than the device (a simulated session at a reduced loop rate, or a stall): the
                # physics still advances in device ticks under the last commanded force, and the encoder is
                # sampled every device tick, so the velocity estimate keeps its window in time.
                self._substeps(min(max(n, 0), 50))
        self._t_last = t
        # encoder quantisation: adding and removing 1.5·2**52 rounds to the nearest integer without a call
        pos, r, ir = self._pos, self._res, self._inv_res
        qx = ((pos[0] * ir + _ROUND) - _ROUND) * r
        qy = ((pos[1] * ir + _ROUND) - _ROUND) * r
        qz = ((pos[2] * ir + _ROUND) - _ROUND) * r
        px, py, pz = self._meas
        jump = self._max_jump
        if not (-jump <= qx - px <= jump and -jump <= qy - py <= jump and -jump <= qz - pz <= jump):
            # NaN fails every comparison, so it lands here too
            if not (math.isfinite(qx) and math.isfinite(qy) and math.isfinite(qz)):
                self._enter_safe_state(f"non-finite position reading ({qx}, {qy}, {qz})")
                qx, qy, qz = px, py, pz
            elif self.fault is None:
                self._enter_safe_state(
                    f"position jumped {math.dist((qx, qy, qz), (px, py, pz)):.1f} mm in one tick (limit {jump:g} mm)"
                )
        q = (qx, qy, qz)
        self._meas = q
        ring = self._ring
        if ring:
            i = self._ring_i
            old = ring[i]  # written len(ring) ticks ago
            ox, oy, oz = old
            if type(old) is list:  # a position _substeps kept: the encoder's rounding, as it would have been then
                ox = ((ox * ir + _ROUND) - _ROUND) * r
                oy = ((oy * ir + _ROUND) - _ROUND) * r
                oz = ((oz * ir + _ROUND) - _ROUND) * r
            ring[i] = q
            i += 1
            self._ring_i = 0 if i == len(ring) else i
            inv = self._vel_scale
            vx, vy, vz = (qx - ox) * inv, (qy - oy) * inv, (qz - oz) * inv
        else:
            vx = vy = vz = 0.0
        fb = self._feedback
        fb["x_mm"] = qx
        fb["y_mm"] = qy
        fb["z_mm"] = qz
        d = self._dir
        values = {
            "x_mm": qx,
            "y_mm": qy,
            "z_mm": qz,
            "vx_mm_s": vx,
            "vy_mm_s": vy,
            "vz_mm_s": vz,
            "dir_x": d[0],
            "dir_y": d[1],
            "dir_z": d[2],
            "button": self._button,
        }
        if self.scene is not None:
            sensed = self.scene.sense(values)
            if sensed:
                values.update(sensed)
        if self.fault is not None:  # the safety layer holds the safe state and logs a device_fault
            return Observation(t, values, faults=(self.fault,))
        return Observation(t, values)

    def write(self, command: Channels) -> None:
        if self.fault is not None:
            return
        fx, fy, fz = command.get("fx_n", 0.0), command.get("fy_n", 0.0), command.get("fz_n", 0.0)
        if not (math.isfinite(fx) and math.isfinite(fy) and math.isfinite(fz)):
            fx = fy = fz = 0.0
        n2 = fx * fx + fy * fy + fz * fz
        cap = self.max_force_n
        if n2 > cap * cap:  # the amplifier saturates along the commanded direction
            s = cap / math.sqrt(n2)
            fx, fy, fz = fx * s, fy * s, fz * s
        f = self._force
        f[0], f[1], f[2] = fx, fy, fz
        fb = self._feedback
        fb["fx_n"], fb["fy_n"], fb["fz_n"] = fx, fy, fz

    def feedback(self) -> dict[str, float]:
        """What the hand feels: the rendered force (N) and where the handle is (mm, proprioception)."""
        return self._feedback

    # ------------------------------------------------------------------ for tests and energy checks
    @property
    def true_state(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Exact handle position (mm) and velocity (mm/s) of the simulation, unquantised."""
        return tuple(self._pos), tuple(self._vel)
