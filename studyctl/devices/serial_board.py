"""The palpation driver board over a serial line (USB-UART) through ``pyserial`` (optional extra ``serial``).

The same messages as over UDP (:mod:`studyctl.devices.board_protocol`), SLIP-framed on the line; everything else
(handshake, sensor freshness, faults, the board's own watchdog, calibration) is :class:`UdpDriverBoard`'s. Install
with ``pip install 'studyctl[serial]'``. The emulator speaks it on a pseudo-terminal:
``python -m studyctl.devices.board_emulator --serial`` prints ``READY /dev/pts/N``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from typing import Any

from studyctl.devices import board_protocol as bp
from studyctl.devices.udp_board import UdpDriverBoard
from studyctl.devices.vendor import run_emulator
from studyctl.errors import DeviceError
from studyctl.plugins.params import Param

EXTRA_HINT = "pip install 'studyctl[serial]'"


def load_serial() -> Any:
    try:
        import serial  # noqa: PLC0415 - optional dependency
    except ImportError as exc:
        raise DeviceError(f"device serial_driver_board needs pyserial: {EXTRA_HINT} ({exc})") from None
    return serial


class SerialDriverBoard(UdpDriverBoard):
    """The palpation driver board (balloon valves, vibration motor, force sensor ADC) over a serial port."""

    name = "serial_driver_board"
    LINK = "serial"
    EXTRA = EXTRA_HINT
    PARAMS = (
        Param("port", "/dev/ttyUSB0", kind=str, source="the board's serial device"),
        Param("baudrate", 115200, 9600, 4_000_000, kind=int, unit="baud", source="CHOSEN: the board's UART rate"),
        *(p for p in UdpDriverBoard.PARAMS if p.name not in ("host", "port")),
    )

    @classmethod
    def check_installed(cls) -> None:
        """Raise DeviceError naming the extra to install when the vendor package is missing (before a session)."""
        load_serial()

    @classmethod
    @contextlib.contextmanager
    def emulate(cls, params: Mapping[str, Any], hang_after_s: float | None = None) -> Iterator[dict[str, Any]]:
        """Start the board emulator on a pseudo-terminal; yield the params that reach it."""
        with run_emulator("studyctl.devices.board_emulator", ["--serial", "--max-runtime", "0"],
                          what="serial driver board", hang_after_s=hang_after_s, hang_flag="--silence-after") as path:
            yield {**dict(params), "port": path}

    def _connect(self) -> Any:
        serial = load_serial()
        port = str(self.params["port"])
        try:
            link = serial.Serial(port, int(self.params["baudrate"]), timeout=0, write_timeout=0, exclusive=True)
        except serial.SerialException as exc:
            text = str(exc)
            if "Errno 13" in text:
                why = ("permission denied; add your user to the group that owns it (e.g. `sudo usermod -aG dialout "
                       "$USER`, then log in again)")
            elif "Errno 11" in text or "exclusively lock" in text:
                why = "busy: another program holds it; close that program (or the other studyctl session)"
            elif "Errno 2" in text:
                why = "no such port; check the USB cable and the name (`python -m serial.tools.list_ports` lists them)"
            else:
                why = f"cannot open it ({text})"
            raise DeviceError(f"serial_driver_board: {port}: {why}") from None
        self._decoder = bp.SlipDecoder()
        return link

    def _recv(self, link: Any, opening: bool = False) -> list[bytes]:
        try:
            waiting = link.in_waiting
            return self._decoder.feed(link.read(waiting)) if waiting else []
        except OSError:  # the adapter was unplugged: as a silent board, the stale-sensor watchdog acts
            return []

    def _send_raw(self, link: Any, datagram: bytes) -> None:
        try:
            link.write(bp.slip_encode(datagram))
        except Exception:  # noqa: BLE001 - unplugged or full: the board's own watchdog turns the outputs off
            pass

    def _close_link(self, link: Any) -> None:
        with contextlib.suppress(Exception):
            link.flush()
        link.close()

    def _where(self) -> str:
        return str(self.params["port"])

    def _check_hint(self) -> str:
        return "connected to this port and set to the same baud rate"
