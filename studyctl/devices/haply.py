"""Haply Inverse3 adapter through Haply's Python API (``HaplyHardwareAPI``, optional extra ``haply``).

Install with ``pip install 'studyctl[haply]'``. The API is imported when the device is opened. One call,
``Inverse3.end_effector_force(forces)``, sends the force (N) and returns the handle's position (m) and velocity
(m/s), so ``read`` sends the last commanded force and ``write`` stores the next one (the same call order as Haply's
own samples). Positions are reported in mm from ``offset_mm`` (default: the workspace centre of Haply's
position-control sample reads as 0).

The force limit (10 N) and the workspace the emulator models are our choice, not a datasheet's: check your unit.
"""

from __future__ import annotations

import time
from typing import Any

from studyctl.devices.vendor import EMULATOR_PARAM, SCALE_PARAM, ForceAdapter, import_sdk
from studyctl.errors import DeviceError
from studyctl.plugins.interfaces import Channels, Observation
from studyctl.plugins.params import Param

EXTRA_HINT = "pip install 'studyctl[haply]'"


def load_sdk(emulator: str = "") -> Any:
    return import_sdk("HaplyHardwareAPI", "STUDYCTL_HAPLY_EMULATOR", emulator,
                      missing=f"device inverse3 needs Haply's Python API (HaplyHardwareAPI): {EXTRA_HINT}")


class Inverse3Device(ForceAdapter):
    """Haply Inverse3 (3 active translational DoF) behind the plugin Device interface."""

    name = "inverse3"
    EXTRA = EXTRA_HINT
    EMULATED_MODEL, EMULATED_WHAT = "inverse3", "Inverse3"
    load_sdk = staticmethod(load_sdk)
    PARAMS = (
        Param("max_force_n", 10.0, 1e-3, 10.0, unit="N", source="CHOSEN: about the Inverse3's peak; check the unit"),
        Param("port", "", kind=str, source="serial port of the Inverse3 (empty: the first detected)"),
        SCALE_PARAM,
        Param("offset_mm", (-18.6, 153.0, -151.0), kind=tuple, unit="mm",
              source="scene position of the device origin (default: the workspace centre reads 0)"),
        Param("ramp_up_s", 1.0, 0.0, 10.0, unit="s", source="CHOSEN: as for the other force devices"),
        EMULATOR_PARAM,
    )  # fmt: skip

    def setup(self, p: dict[str, Any]) -> None:
        self.force_limits(p, sensor_stale_s=0.01)
        self._k = 1000.0 * float(p["scale"])
        self._offset = tuple(float(v) for v in p["offset_mm"])
        self._dev: Any = None
        self._stream: Any = None
        self._info: dict[str, Any] = {}

    def identity(self) -> dict[str, Any]:
        return {"model": "Inverse3", **self._info} if self._info else {}

    def open(self) -> None:
        api = load_sdk(str(self.params.get("emulator") or ""))
        port = str(self.params["port"]) or next(iter(api.detect_inverse3s()), "")
        if not port:
            raise DeviceError("device inverse3: no Inverse3 found; check the USB cable and power (and on Linux that "
                              "your user is in the dialout group)")
        try:
            self._stream = api.SerialStream(port)
            self._dev = api.Inverse3(self._stream)
            self._info = dict(self._dev.device_wakeup_dict())
        except (OSError, TimeoutError) as exc:
            self._dev = None
            raise DeviceError(f"device inverse3: cannot open {port} ({exc}); is another program using it?") from None

    def read(self, t: float) -> Observation:
        if self._dev is None:
            raise DeviceError("device inverse3: read before open()")
        try:
            pos, vel = self._dev.end_effector_force(self._force)
        except (OSError, TimeoutError) as exc:
            raise DeviceError(f"device inverse3: the device stopped answering ({exc})") from None
        k, o = self._k, self._offset
        values = {"x_mm": o[0] + k * pos[0], "y_mm": o[1] + k * pos[1], "z_mm": o[2] + k * pos[2],
                  "vx_mm_s": k * vel[0], "vy_mm_s": k * vel[1], "vz_mm_s": k * vel[2]}
        return Observation(t, values, sample_t=t)

    def write(self, command: Channels) -> None:
        if self._dev is None:
            raise DeviceError("device inverse3: write before open()")
        self.store_force(command)  # sent by the next read's end_effector_force

    def close(self) -> None:
        dev, self._dev = self._dev, None
        if dev is None:
            return
        try:
            dev.end_effector_force([0.0, 0.0, 0.0])
            time.sleep(0.002)
        except (OSError, TimeoutError):
            pass  # the firmware's own timeout drops the forces
        finally:
            close = getattr(self._stream, "close", None)
            if callable(close):
                close()
