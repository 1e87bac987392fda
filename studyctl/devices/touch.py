"""3D Systems Touch / PHANToM Omni adapter through ``pyOpenHaptics`` (PyPI ``pyopenhaptics``, optional extra).

Install with ``pip install 'studyctl[openhaptics]'`` and the OpenHaptics SDK (libHD). The wrapper is imported when
the device is opened, never at import time.

OpenHaptics runs its own servo thread at 1 kHz; the wrapper schedules a Python callback in it (begin frame, the
callback, end frame). Here the callback only copies the newest handle state into this adapter and applies the
newest force command, so the engine's loop (in the servo process) and the HD thread meet in two small buffers:
``read`` returns the state the callback stored (``sample_t`` = when, so a stopped HD servo shows up as a stale
sensor and the safety layer's watchdog acts), ``write`` sets the force the next callback applies. The wrapper
stops the callback on any HD error (research/haptics.md), which is then exactly such a stale sensor.

Frames and units: OpenHaptics reports the pose as a 4x4 transform in mm (translation in the last row); forces are
in N in the device frame, clamped by the safety layer to 3.3 N (the Omni/Touch peak, CHAI3D's driver table).
"""

from __future__ import annotations

import time
from typing import Any

from studyctl.devices.vendor import EMULATOR_PARAM, SCALE_PARAM, ForceAdapter, import_sdk
from studyctl.errors import DeviceError
from studyctl.plugins.interfaces import Channels, Observation
from studyctl.plugins.params import Param

EXTRA_HINT = "pip install 'studyctl[openhaptics]'"


def load_sdk(emulator: str = "") -> Any:
    """The ``pyOpenHaptics`` modules (hd, hd_callback, hd_device), or a DeviceError naming the extra."""
    how = {"missing": f"device touch needs the OpenHaptics wrapper (pyopenhaptics): {EXTRA_HINT} and install the "
                      "OpenHaptics SDK",
           "no_library": "device touch: the OpenHaptics library (libHD) could not be loaded ({exc}); install the "
                         f"OpenHaptics SDK and {EXTRA_HINT}"}  # the wrapper loads libHD at import
    return tuple(import_sdk(f"pyOpenHaptics.{name}", "STUDYCTL_HD_EMULATOR", emulator, **how)
                 for name in ("hd", "hd_callback", "hd_device"))


class TouchDevice(ForceAdapter):
    """PHANToM Omni / 3D Systems Touch (3 active translational DoF) behind the plugin Device interface."""

    name = "touch"
    EXTRA = "pip install 'studyctl[openhaptics]' + the OpenHaptics SDK"
    EMULATED_MODEL, EMULATED_WHAT = "touch", "Touch"
    load_sdk = staticmethod(load_sdk)
    PARAMS = (
        Param("max_force_n", 3.3, 1e-3, 3.3, unit="N", source="Omni/Touch peak force (CHAI3D driver table)"),
        Param("device_name", "Default Device", kind=str, source="the OpenHaptics device configuration name"),
        SCALE_PARAM,
        Param("offset_mm", (0.0, 0.0, 0.0), kind=tuple, unit="mm", source="scene position of the device origin"),
        Param("ramp_up_s", 1.0, 0.0, 10.0, unit="s", source="CHOSEN: CHAI3D ramps over 2 s"),
        Param("sensor_stale_s", 0.01, 0.002, 1.0, unit="s", source="CHOSEN: 10 missed HD servo ticks"),
        EMULATOR_PARAM,
    )  # fmt: skip

    def setup(self, p: dict[str, Any]) -> None:
        self.force_limits(p, sensor_stale_s=float(p["sensor_stale_s"]))
        self._k = float(p["scale"])
        self._offset = tuple(float(v) for v in p["offset_mm"])
        self._hd: Any = None
        self._device: Any = None
        self._cmd = [0.0, 0.0, 0.0]
        self._pose = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]  # x y z vx vy vz buttons (mm, mm/s)
        self._stamp = 0.0  # perf_counter of the last HD callback
        self._t0 = 0.0

    def identity(self) -> dict[str, Any]:
        hd = self._hd
        return {"model": hd.get_model(), "vendor": hd.get_vendor()} if hd is not None else {}

    def open(self) -> None:
        hd, hd_callback, hd_device = load_sdk(str(self.params.get("emulator") or ""))
        self._hd = hd
        velocity = getattr(hd, "_get_velocity", None)

        def servo() -> None:  # runs in the HD servo thread, every tick
            m = hd.get_transform()
            pose = self._pose
            pose[0], pose[1], pose[2] = m[3][0], m[3][1], m[3][2]
            if velocity is not None:
                v = velocity()
                pose[3], pose[4], pose[5] = v[0], v[1], v[2]
            pose[6] = float(hd.get_buttons())
            hd.set_force(self._cmd)
            self._stamp = time.perf_counter()

        self._t0 = time.perf_counter()
        self._stamp = 0.0
        device = hd_device.HapticDevice(hd_callback.hd_callback(servo), str(self.params["device_name"]), "async")
        if getattr(device, "id", None) is None:
            self._hd = None
            raise DeviceError(f"device touch: OpenHaptics could not initialise {self.params['device_name']!r}; check "
                              "the cable, that Touch Setup/Diagnostic sees it, and that no other program holds it")
        self._device = device
        deadline = time.monotonic() + 1.0
        while self._stamp == 0.0:  # the first servo tick: a fresh sample for the first read
            if time.monotonic() > deadline:
                self.close()
                raise DeviceError("device touch: the OpenHaptics servo loop did not start within 1 s")
            time.sleep(0.001)

    def read(self, t: float) -> Observation:
        if self._hd is None:
            raise DeviceError("device touch: read before open()")
        x, y, z, vx, vy, vz, buttons = self._pose
        k, o = self._k, self._offset
        values = {"x_mm": o[0] + k * x, "y_mm": o[1] + k * y, "z_mm": o[2] + k * z,
                  "vx_mm_s": k * vx, "vy_mm_s": k * vy, "vz_mm_s": k * vz, "button": 1.0 if buttons else 0.0}
        age = time.perf_counter() - self._stamp  # how old the HD thread's newest sample is
        return Observation(t, values, sample_t=t - age)

    def write(self, command: Channels) -> None:
        if self._hd is None:
            raise DeviceError("device touch: write before open()")
        # a new list, not filled in place: the HD thread reads _cmd at any moment and must never see half a command
        self._cmd = [float(command.get("fx_n", 0.0)), float(command.get("fy_n", 0.0)), float(command.get("fz_n", 0.0))]
        fb = self._feedback
        fb["fx_n"], fb["fy_n"], fb["fz_n"] = self._cmd

    def close(self) -> None:
        device, self._device = self._device, None
        self._cmd = [0.0, 0.0, 0.0]
        if device is not None:
            time.sleep(0.003)  # a few servo ticks apply the zero force before the scheduler stops
            device.close()
        self._hd = None
