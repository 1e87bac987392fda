"""Hardware adapter for the haptic driver board over UDP (message format: :mod:`studyctl.devices.board_protocol`).

``open()`` says HELLO and waits for the board's STATUS (a clear error if none comes); the board then
streams SENSOR packets at the requested rate. ``read(t)`` drains the socket without blocking and returns
the newest sample: its ADC count, the calibrated force (A201 curve), and ``sample_t`` = the trial time
at which the newest packet arrived, so a silent board shows up as a stale sensor in the safety layer.
ADC values outside 0..1023 and board-reported faults come back in ``Observation.faults``. ``write()``
sends a COMMAND (which also feeds the board's own output watchdog); ``close()`` sends SAFE and BYE.

Test against the emulator: ``python -m studyctl.devices.board_emulator --port 0`` (see its docstring).
"""

from __future__ import annotations

import math
import select
import socket
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from studyctl.devices import board_protocol as bp
from studyctl.devices.palpation import palpation_limits
from studyctl.errors import DatagramError, DeviceError
from studyctl.models.palpation_hw import A201
from studyctl.plugins.interfaces import Channels, Device, Observation, Scene
from studyctl.plugins.params import Param, validate_params


class UdpDriverBoard(Device):
    """The palpation driver board (balloon valves, vibration motor, force sensor ADC) over UDP."""

    name = "udp_driver_board"
    simulated = False
    PARAMS = (
        Param("host", "127.0.0.1", kind=str, source="the board's address"),
        Param("port", 47800, 1, 65535, kind=int, source="the board's UDP port"),
        Param("rate_hz", 50.0, 1.0, 1000.0, unit="Hz", source="paper: sensor updated near 50 Hz"),
        Param("watchdog_ms", 250, 20, 10000, kind=int, unit="ms", source="CHOSEN: board output watchdog"),
        Param("connect_timeout_s", 1.0, 0.05, 30.0, unit="s", source="CHOSEN"),
        Param("sensor_stale_s", 0.1, 0.005, 10.0, unit="s", source="CHOSEN: 5 missed 50 Hz samples"),
        Param("ramp_up_s", 0.2, 0.0, 5.0, unit="s", source="CHOSEN: output ramp after enable"),
    )

    def __init__(
        self,
        params: Mapping[str, Any] | None = None,
        scene: Scene | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        checked = validate_params("udp_driver_board device", params, self.PARAMS)
        super().__init__(checked, scene, rng)
        self.limits = palpation_limits(checked["ramp_up_s"], checked["sensor_stale_s"])
        self.address = (checked["host"], checked["port"])
        self.sensor = A201
        self._sock: socket.socket | None = None
        self._seq = 0
        self.dropped = 0
        self.status: dict[str, int] = {}
        self._latest: tuple[int, int, int, int, int, int] | None = None  # seq, time_us, adc, status, b, v
        self._sample_t: float | None = None

    # -- Device --------------------------------------------------------------------------------------
    def open(self) -> None:
        if self._sock is not None:
            return
        self._latest = None
        self.status = {}
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setblocking(False)
        try:
            sock.connect(self.address)
            self._send(sock, bp.HELLO, int(self.params["rate_hz"]), int(self.params["watchdog_ms"]))
            deadline = time.monotonic() + self.params["connect_timeout_s"]
            # Wait for the board's STATUS and its first SENSOR packet, so the first tick has a fresh sample.
            while self._latest is None or not self.status:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    what = "no answer from" if not self.status else "no sensor data from"
                    raise DeviceError(
                        f"udp_driver_board: {what} the board at {self.address[0]}:{self.address[1]} within "
                        f"{self.params['connect_timeout_s']:g} s; check that it is powered, on this network and the "
                        "port is right"
                    )
                ready, _, _ = select.select([sock], [], [], remaining)
                if not ready:
                    continue
                try:
                    data = sock.recv(2048)
                except ConnectionRefusedError:
                    raise DeviceError(
                        f"udp_driver_board: nothing listens at {self.address[0]}:{self.address[1]} (connection "
                        "refused); start the board or its emulator"
                    ) from None
                pkt = self._parse(data)
                if pkt is None:
                    continue
                if pkt.type == bp.STATUS:
                    fw, bits, rate, wd, rejected = pkt.fields
                    self.status = {"firmware": fw, "adc_bits": bits, "rate_hz": rate, "watchdog_ms": wd,
                                   "rejected": rejected}
                    if bits != self.sensor.adc_bits:
                        raise DeviceError(
                            f"udp_driver_board: the board reports a {bits}-bit ADC; studyctl's A201 calibration "
                            f"expects {self.sensor.adc_bits} bits"
                        )
                elif pkt.type == bp.SENSOR:
                    self._latest = (pkt.seq, *pkt.fields)
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        self._sample_t = None  # the first read() stamps the sample that arrived during open()

    def read(self, t: float) -> Observation:
        if self._sock is None:
            raise DeviceError("udp_driver_board: read before open(); the engine must open the device first")
        fresh = False
        while True:
            try:
                data = self._sock.recv(2048)
            except BlockingIOError:
                break
            except ConnectionRefusedError:  # ICMP port unreachable: the board went away
                break
            pkt = self._parse(data)
            if pkt is None or pkt.type != bp.SENSOR:
                continue
            if self._latest is None or _newer(pkt.seq, self._latest[0]):
                self._latest = (pkt.seq, *pkt.fields)
                fresh = True
        if fresh or (self._sample_t is None and self._latest is not None):
            self._sample_t = t
        elif self._sample_t is None:
            self._sample_t = -math.inf
        if self._latest is None:
            return Observation(t, {"adc": math.nan, "force_n": math.nan}, sample_t=self._sample_t,
                               faults=("no sensor packet received yet",))
        _seq, _time_us, adc, status, b, v = self._latest
        faults: list[str] = []
        if 0 <= adc <= self.sensor.adc_max:
            force = self.sensor.force_of_count(adc)
        else:
            force = math.nan
            faults.append(f"adc_out_of_range: {adc} not in 0..{self.sensor.adc_max}")
        if status & bp.ST_ADC_FAULT:
            faults.append("board reports an ADC fault")
        if status & bp.ST_WATCHDOG:
            faults.append("board output watchdog tripped (commands arrived too late)")
        values = {"adc": float(adc), "force_n": force, "balloon_pct_applied": b / bp.SCALE,
                  "vibration_pct_applied": v / bp.SCALE}
        return Observation(t, values, sample_t=self._sample_t, faults=tuple(faults))

    def write(self, command: Channels) -> None:
        if self._sock is None:
            return
        b = _wire(command.get("balloon_pct", 0.0))
        v = _wire(command.get("vibration_pct", 0.0))
        self._send(self._sock, bp.COMMAND, b, v)

    def feedback(self) -> dict[str, float]:
        if self._latest is None:
            return {}
        return {"balloon_pct_applied": self._latest[4] / bp.SCALE, "vibration_pct_applied": self._latest[5] / bp.SCALE}

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is None:
            return
        try:
            for kind in (bp.SAFE, bp.SAFE, bp.BYE):  # SAFE twice: UDP may drop one
                self._send(sock, kind)
        finally:
            sock.close()

    # -- internals -----------------------------------------------------------------------------------
    def _send(self, sock: socket.socket, kind: int, *fields: int) -> None:
        self._seq = (self._seq + 1) & 0xFFFFFFFF
        try:
            sock.send(bp.encode(kind, self._seq, *fields))
        except (ConnectionRefusedError, BlockingIOError):
            pass  # the board is gone or busy; the stale-sensor watchdog will act

    def _parse(self, data: bytes) -> bp.Packet | None:
        try:
            return bp.decode(data)
        except DatagramError:
            self.dropped += 1
            return None


def _wire(value: float) -> int:
    """Percent → wire units (0.1 %), clamped to 0..1000; NaN → 0 (the safety layer should never send it)."""
    if not isinstance(value, int | float) or not math.isfinite(value):
        return 0
    return int(round(min(max(value, 0.0), 100.0) * bp.SCALE))


def _newer(a: int, b: int) -> bool:
    """Sequence ``a`` is after ``b`` (32-bit wrap-around)."""
    return 0 < ((a - b) & 0xFFFFFFFF) < 0x80000000
