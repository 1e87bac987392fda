"""Force Dimension omega.6 adapter through the ``forcedimension_core`` Python bindings (optional extra).

Install with ``pip install 'studyctl[omega]'`` (and the vendor's SDK, whose ``libdhd`` the bindings load).
The bindings are imported when the device is opened, never at import time, so studyctl runs without them.

Frames and units: the SDK reports metres and the wrist's rotation matrix; this adapter reports the
handle position in mm (``x_mm``… after ``scale`` and ``offset_mm``), the SDK's windowed velocity estimate
in mm/s, the pen axis (``dir_x``… — a column of the wrist rotation, ``pen_axis``), and ``button`` (index
0). Forces are written in N in the device frame; the SDK's own clamp (``setMaxForce``) and watchdog
(forces off and brakes on when no command arrives for ``watchdog_ms``) stay on underneath the safety layer.

A 1 kHz loop in Python must not share the interpreter with a user interface or logging: run trials on
this device through :func:`studyctl.engine.servo.run_trial_in_servo_process`, which runs the loop in its
own process and measures the period jitter.
"""

from __future__ import annotations

from typing import Any

from studyctl.devices.vendor import EMULATOR_PARAM, SCALE_PARAM, ForceAdapter, import_sdk
from studyctl.errors import DeviceError, ModelParameterError
from studyctl.plugins.interfaces import Channels, Observation
from studyctl.plugins.params import Param

EXTRA_HINT = "pip install 'studyctl[omega]'"


def load_sdk(emulator: str = "") -> Any:
    """The ``forcedimension_core.dhd`` module, or a DeviceError naming the extra to install.

    ``emulator``: the name of a running device emulator (:mod:`studyctl.devices.emulators.shm_device`); the SDK is
    then studyctl's stand-in with the same API, driving that emulator."""
    return import_sdk(
        "forcedimension_core.dhd", "STUDYCTL_FD_EMULATOR", emulator,
        missing=f"device omega6 needs the Force Dimension bindings (forcedimension-core): {EXTRA_HINT} and install "
                "the Force Dimension SDK",
        no_library="device omega6: the Force Dimension SDK library could not be loaded ({exc}); install the SDK "
                   f"from Force Dimension and the bindings with {EXTRA_HINT}",
    )


class Omega6Device(ForceAdapter):
    """omega.6 (3 active translational DoF, passive wrist) behind the plugin Device interface."""

    name = "omega6"
    EMULATED_MODEL, EMULATED_WHAT = "omega6", "omega.6"
    WORLD = True  # a virtual participant can rehearse on its emulator (run --rehearse --virtual)
    load_sdk = staticmethod(load_sdk)
    PARAMS = (
        Param("max_force_n", 12.0, 1e-3, 12.0, unit="N", source="omega.6 peak force (CHAI3D driver spec)"),
        SCALE_PARAM,
        Param("offset_mm", (0.0, 0.0, 0.0), kind=tuple, unit="mm", source="scene position of the device origin"),
        Param("pen_axis", "-x", choices=("x", "y", "z", "-x", "-y", "-z"), kind=str,
              source="CHOSEN: the wrist-frame axis along the needle; check on the device"),
        Param("button", 0, 0, 15, kind=int, source="the pen's button index"),
        Param("watchdog_ms", 10.0, 0.0, 1000.0, unit="ms",
              source="SDK watchdog: forces off and brakes when no command arrives this long (0 = off)"),
        Param("ramp_up_s", 1.0, 0.0, 10.0, unit="s", source="CHOSEN: CHAI3D ramps over 2 s"),
        Param("max_force_rate_n_per_s", 2000.0, 1.0, 1e6, unit="N/s",
              source="CHOSEN: a puncture drop takes at least 0.5 ms per newton"),
        Param("device_id", -1, -1, 64, kind=int, source="-1: the first available device"),
        EMULATOR_PARAM,
    )  # fmt: skip

    def setup(self, p: dict[str, Any]) -> None:
        if len(p["offset_mm"]) != 3:
            raise ModelParameterError(f"device omega6: offset_mm = {list(p['offset_mm'])} must be [x, y, z] in mm")
        axis = p["pen_axis"]
        self.params = p
        self._col = "xyz".index(axis[-1])
        self._sign = -1.0 if axis.startswith("-") else 1.0
        self._offset = tuple(float(v) for v in p["offset_mm"])
        self._scale = float(p["scale"])
        self.force_limits(p, sensor_stale_s=0.01, max_rate_per_s=p["max_force_rate_n_per_s"])
        self._dhd: Any = None
        self._id = -1
        self._pos = [0.0, 0.0, 0.0]
        self._vel = [0.0, 0.0, 0.0]
        self._rot = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]

    def _check(self, ret: int, op: str) -> None:
        if ret is not None and ret < 0:
            raise DeviceError(f"device omega6: {op} failed: {self._dhd.errorGetLastStr()}")

    def open(self) -> None:
        dhd = load_sdk(str(self.params.get("emulator") or ""))
        self._dhd = dhd
        want = int(self.params["device_id"])
        self._id = dhd.open() if want < 0 else dhd.openID(want)
        if self._id < 0:
            raise DeviceError(
                f"device omega6: no Force Dimension device could be opened ({dhd.errorGetLastStr()}); "
                "check the USB cable, power and that no other program holds it"
            )
        self._check(dhd.setMaxForce(self.max_force_n, ID=self._id), "setMaxForce")
        watchdog = float(self.params["watchdog_ms"])
        expert = getattr(dhd, "expert", None)
        if watchdog > 0 and expert is not None and hasattr(expert, "setWatchdog"):
            self._check(expert.setWatchdog(max(1, round(watchdog * 8)), ID=self._id), "setWatchdog")  # 125 µs units
        self._check(dhd.enableForce(True, ID=self._id), "enableForce")

    def identity(self) -> dict[str, Any]:
        """The SDK's account of the open device: model, serial number, communication rate, force limit."""
        dhd = self._dhd
        if dhd is None:
            return {}
        out: dict[str, Any] = {"model": dhd.getSystemName(ID=self._id), "serial": dhd.getSerialNumber(ID=self._id)}
        for key, fn in (("com_khz", "getComFrequency"), ("max_force_n", "getMaxForce")):
            if hasattr(dhd, fn):
                out[key] = getattr(dhd, fn)(ID=self._id)
        return out

    def calibrate(self, seconds: float) -> dict[str, Any]:
        """Zero the position: hold the handle at the scene's reference point; its mean position over ``seconds``
        then reads as the configured ``offset_mm``."""
        import time  # noqa: PLC0415

        dhd = self._dhd
        if dhd is None:
            raise DeviceError("device omega6: calibrate before open()")
        pts = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self._check(dhd.getPosition(out=self._pos, ID=self._id), "getPosition")
            pts.append(tuple(self._pos))
            time.sleep(0.002)
        k = 1000.0 * self._scale
        mean = [sum(p[i] for p in pts) / len(pts) for i in range(3)]
        spread = [max(p[i] for p in pts) - min(p[i] for p in pts) for i in range(3)]
        offset = [round(self._offset[i] - k * mean[i], 6) for i in range(3)]
        return {"params": {"offset_mm": offset},
                "detail": {"what": "position zero: mean handle position at the reference point", "samples": len(pts),
                           "mean_m": mean, "spread_mm": [1000.0 * x for x in spread]}}

    def read(self, t: float) -> Observation:
        dhd = self._dhd
        if dhd is None:
            raise DeviceError("device omega6: read before open()")
        self._check(dhd.getPosition(out=self._pos, ID=self._id), "getPosition")
        self._check(dhd.getLinearVelocity(out=self._vel, ID=self._id), "getLinearVelocity")
        self._check(dhd.getOrientationFrame(out=self._rot, ID=self._id), "getOrientationFrame")
        button = dhd.getButton(index=int(self.params["button"]), ID=self._id)
        self._check(button, "getButton")
        k, o, s = 1000.0 * self._scale, self._offset, self._sign
        p, v, r, c = self._pos, self._vel, self._rot, self._col
        values = {
            "x_mm": o[0] + k * p[0],
            "y_mm": o[1] + k * p[1],
            "z_mm": o[2] + k * p[2],
            "vx_mm_s": k * v[0],
            "vy_mm_s": k * v[1],
            "vz_mm_s": k * v[2],
            "dir_x": s * r[0][c],
            "dir_y": s * r[1][c],
            "dir_z": s * r[2][c],
            "button": 1.0 if button else 0.0,
        }
        return Observation(t, values, sample_t=t)

    def write(self, command: Channels) -> None:
        if self._dhd is None:
            raise DeviceError("device omega6: write before open()")
        self._check(self._dhd.setForce(self.store_force(command), ID=self._id), "setForce")

    def close(self) -> None:
        dhd, self._dhd = self._dhd, None
        if dhd is None:
            return
        try:
            dhd.setForce([0.0, 0.0, 0.0], ID=self._id)
            dhd.enableForce(False, ID=self._id)
        finally:
            dhd.close(self._id)
