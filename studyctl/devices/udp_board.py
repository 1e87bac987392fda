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

import contextlib
import math
import select
import socket
import time
from collections.abc import Iterator, Mapping
from typing import Any

from studyctl.devices import board_protocol as bp
from studyctl.devices.base import ParamDevice
from studyctl.devices.palpation import palpation_limits
from studyctl.errors import DatagramError, DeviceError
from studyctl.models.palpation_hw import A201
from studyctl.plugins.interfaces import Channels, Observation
from studyctl.plugins.params import Param


class UdpDriverBoard(ParamDevice):
    """The palpation driver board (balloon valves, vibration motor, force sensor ADC) over UDP."""

    name = "udp_driver_board"
    LINK = "UDP"  # how the board is reached, in its identity
    simulated = False
    PARAMS = (
        Param("host", "127.0.0.1", kind=str, source="the board's address"),
        Param("port", 47800, 1, 65535, kind=int, source="the board's UDP port"),
        Param("rate_hz", 50.0, 1.0, 1000.0, unit="Hz", source="paper: sensor updated near 50 Hz"),
        Param("watchdog_ms", 250, 20, 10000, kind=int, unit="ms", source="CHOSEN: board output watchdog"),
        Param("connect_timeout_s", 1.0, 0.05, 30.0, unit="s", source="CHOSEN"),
        Param("sensor_stale_s", 0.1, 0.005, 10.0, unit="s", source="CHOSEN: 5 missed 50 Hz samples"),
        Param("ramp_up_s", 0.2, 0.0, 5.0, unit="s", source="CHOSEN: output ramp after enable"),
        Param("zero_n", 0.0, -5.0, 5.0, unit="N", source="sensor reading at rest (studyctl device calibrate)"),
    )

    def setup(self, checked: dict[str, Any]) -> None:
        self.limits = palpation_limits(checked["ramp_up_s"], checked["sensor_stale_s"])
        self.address = (checked.get("host"), checked.get("port"))
        self._zero = float(checked["zero_n"])
        self.sensor = A201
        self._sock: Any = None  # the open link (a UDP socket, or a serial port)
        self._seq = 0
        self.dropped = 0
        self.status: dict[str, int] = {}
        self._latest: tuple[int, int, int, int, int, int] | None = None  # seq, time_us, adc, status, b, v
        self._sample_t: float | None = None

    @classmethod
    @contextlib.contextmanager
    def emulate(cls, params: Mapping[str, Any], hang_after_s: float | None = None,
                world: bool = False) -> Iterator[dict[str, Any]]:
        """Start the board emulator (:mod:`studyctl.devices.board_emulator`) on loopback; yield the params
        that reach it (a rehearsal's device). ``world``: also its world block for a virtual participant's hand
        (yielded as ``world: {kind, block}``, see :mod:`studyctl.devices.world`)."""
        from studyctl.devices.emulation import start_emulator  # noqa: PLC0415

        args = ["--max-runtime", "0", "--exit-with-parent"]
        if hang_after_s is not None:  # tests: a board that stops answering
            args += ["--silence-after", str(hang_after_s)]
        if world:
            args.append("--world")
        with start_emulator("studyctl.devices.board_emulator", args, what="driver board") as address:
            port, _, block = address.partition(" ")
            out = {**dict(params), "host": "127.0.0.1", "port": int(port)}
            if world:
                out["world"] = {"kind": "palpation_board", "block": block}
            yield out

    def identity(self) -> dict[str, Any]:
        """What the board reported in its STATUS (firmware, ADC bits, rate, watchdog) and where it is."""
        return {"model": f"palpation driver board ({self.LINK})", "address": self._where(), **self.status}

    def calibrate(self, seconds: float) -> dict[str, Any]:
        """Zero the force sensor: with nothing touching it, the mean force over ``seconds`` becomes ``zero_n``."""
        forces = []
        end = time.monotonic() + seconds
        t0 = time.monotonic()
        while time.monotonic() < end:
            obs = self.read(time.monotonic() - t0)
            if not obs.faults and math.isfinite(obs.values["force_n"]):
                forces.append(obs.values["force_n"] + self._zero)
            time.sleep(0.01)
        if not forces:
            raise DeviceError(f"{self.name}: no valid sensor reading while calibrating; check the sensor cable")
        mean = sum(forces) / len(forces)
        sd = (sum((f - mean) ** 2 for f in forces) / max(1, len(forces) - 1)) ** 0.5
        return {"params": {"zero_n": round(mean, 6)},
                "detail": {"what": "force sensor zero: mean force at rest", "samples": len(forces), "sd_n": sd}}

    # -- Device --------------------------------------------------------------------------------------
    def open(self) -> None:
        if self._sock is not None:
            return
        self._latest = None
        self.status = {}
        link = self._connect()
        try:
            self._send(link, bp.HELLO, int(self.params["rate_hz"]), int(self.params["watchdog_ms"]))
            deadline = time.monotonic() + self.params["connect_timeout_s"]
            # Wait for the board's STATUS and its first SENSOR packet, so the first tick has a fresh sample.
            while self._latest is None or not self.status:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    what = "no answer from" if not self.status else "no sensor data from"
                    raise DeviceError(
                        f"{self.name}: {what} the board at {self._where()} within "
                        f"{self.params['connect_timeout_s']:g} s; check that it is powered, {self._check_hint()}"
                    )
                ready, _, _ = select.select([link], [], [], remaining)
                if not ready:
                    continue
                for data in self._recv(link, opening=True):
                    pkt = self._parse(data)
                    if pkt is None:
                        continue
                    if pkt.type == bp.STATUS:
                        fw, bits, rate, wd, rejected = pkt.fields
                        self.status = {"firmware": fw, "adc_bits": bits, "rate_hz": rate, "watchdog_ms": wd,
                                       "rejected": rejected}
                        if bits != self.sensor.adc_bits:
                            raise DeviceError(
                                f"{self.name}: the board reports a {bits}-bit ADC; studyctl's A201 calibration "
                                f"expects {self.sensor.adc_bits} bits"
                            )
                    elif pkt.type == bp.SENSOR:
                        self._latest = (pkt.seq, *pkt.fields)
        except BaseException:
            self._close_link(link)
            raise
        self._sock = link
        self._sample_t = None  # the first read() stamps the sample that arrived during open()

    # -- transport (UDP here; the serial board overrides these) -------------------------------------------------
    def _connect(self) -> Any:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setblocking(False)
        sock.connect(self.address)
        return sock

    def _recv(self, link: Any, opening: bool = False) -> list[bytes]:
        """Every datagram waiting now (never blocks)."""
        out = []
        while True:
            try:
                out.append(link.recv(2048))
            except BlockingIOError:
                return out
            except ConnectionRefusedError:  # ICMP port unreachable: nobody listens (or the board went away)
                if opening:
                    raise DeviceError(
                        f"udp_driver_board: nothing listens at {self.address[0]}:{self.address[1]} (connection "
                        "refused); start the board or its emulator"
                    ) from None
                return out

    def _send_raw(self, link: Any, datagram: bytes) -> None:
        try:
            link.send(datagram)
        except (ConnectionRefusedError, BlockingIOError):
            pass  # the board is gone or busy; the stale-sensor watchdog will act

    def _close_link(self, link: Any) -> None:
        link.close()

    def _where(self) -> str:
        return f"{self.address[0]}:{self.address[1]}"

    def _check_hint(self) -> str:
        return "on this network and the port is right"

    def read(self, t: float) -> Observation:
        if self._sock is None:
            raise DeviceError(f"{self.name}: read before open(); the engine must open the device first")
        fresh = False
        for data in self._recv(self._sock):
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
            force = self.sensor.force_of_count(adc) - self._zero
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
            raise DeviceError(f"{self.name}: write before open(); the engine must open the device first")
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
            self._close_link(sock)

    # -- internals -----------------------------------------------------------------------------------
    def _send(self, link: Any, kind: int, *fields: int) -> None:
        self._seq = (self._seq + 1) & 0xFFFFFFFF
        self._send_raw(link, bp.encode(kind, self._seq, *fields))

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
