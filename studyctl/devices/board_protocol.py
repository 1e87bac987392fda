"""Wire format between studyctl and the haptic driver board (balloon valve array + vibration motor + sensor).

The seed-000 controller talked to its driver over Wi-Fi; this is studyctl's documented UDP format for
such a board. :class:`studyctl.devices.udp_board.UdpDriverBoard` is the host side and
:mod:`studyctl.devices.board_emulator` a board that runs as a separate process for tests and rehearsals.

Every datagram is little-endian::

    offset size field
    0      2    magic  b"SB"
    2      1    version (1)
    3      1    type    (below)
    4      4    seq     u32, per sender, wraps
    8      n    body    (per type)
    8+n    4    crc32   zlib.crc32 of bytes 0 .. 8+n-1

Host → board
    ``0x01 HELLO``    body ``rate_hz u16, watchdog_ms u16``: start streaming SENSOR packets at rate_hz to
                      the sender; the board's output watchdog is armed with watchdog_ms. Answered by STATUS.
    ``0x02 COMMAND``  body ``balloon u16, vibration u16``: control amounts in 0.1 % (0..1000). Feeds the
                      watchdog. Out-of-range values are rejected (outputs unchanged, status bit 3).
    ``0x03 SAFE``     no body: all outputs off at once.
    ``0x04 BYE``      no body: outputs off, stop streaming.

Board → host
    ``0x81 SENSOR``   body ``board_time_us u32, adc u16, status u16, balloon u16, vibration u16``: the raw
                      10-bit ADC count of the force sensor and the control amounts the board is applying.
    ``0x82 STATUS``   body ``firmware u16, adc_bits u8, rate_hz u16, watchdog_ms u16, rejected u32``.

Status bits: 0 watchdog tripped (no COMMAND within watchdog_ms: outputs forced off until the next
COMMAND), 1 ADC fault, 2 balloon at the regulator limit, 3 a COMMAND was rejected since the last SENSOR.

Datagrams with a wrong magic, version, length or CRC are dropped and counted by the receiver.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from studyctl.errors import DatagramError

MAGIC = b"SB"
VERSION = 1
HEADER = struct.Struct("<2sBBI")
CRC = struct.Struct("<I")

HELLO, COMMAND, SAFE, BYE = 0x01, 0x02, 0x03, 0x04
SENSOR, STATUS = 0x81, 0x82

BODIES = {
    HELLO: struct.Struct("<HH"),
    COMMAND: struct.Struct("<HH"),
    SAFE: struct.Struct("<"),
    BYE: struct.Struct("<"),
    SENSOR: struct.Struct("<IHHHH"),
    STATUS: struct.Struct("<HBHHI"),
}

ST_WATCHDOG = 1 << 0
ST_ADC_FAULT = 1 << 1
ST_REGULATOR = 1 << 2
ST_REJECTED = 1 << 3

SCALE = 10  # control amount units per percent on the wire (0.1 % resolution)


@dataclass(frozen=True)
class Packet:
    type: int
    seq: int
    fields: tuple[int, ...]


def encode(kind: int, seq: int, *fields: int) -> bytes:
    """One datagram of ``kind`` with sequence number ``seq`` and the body fields."""
    body = BODIES[kind].pack(*fields)
    head = HEADER.pack(MAGIC, VERSION, kind, seq & 0xFFFFFFFF)
    payload = head + body
    return payload + CRC.pack(zlib.crc32(payload) & 0xFFFFFFFF)


def decode(data: bytes) -> Packet:
    """Parse and check a datagram; raise DatagramError naming what is wrong."""
    if len(data) < HEADER.size + CRC.size:
        raise DatagramError(f"datagram of {len(data)} bytes is shorter than a header")
    magic, version, kind, seq = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise DatagramError(f"bad magic {magic!r}")
    if version != VERSION:
        raise DatagramError(f"unsupported version {version}")
    body = BODIES.get(kind)
    if body is None:
        raise DatagramError(f"unknown packet type 0x{kind:02x}")
    expected = HEADER.size + body.size + CRC.size
    if len(data) != expected:
        raise DatagramError(f"type 0x{kind:02x} must be {expected} bytes, got {len(data)}")
    (crc,) = CRC.unpack_from(data, expected - CRC.size)
    if crc != zlib.crc32(data[: expected - CRC.size]) & 0xFFFFFFFF:
        raise DatagramError("CRC mismatch")
    return Packet(kind, seq, body.unpack_from(data, HEADER.size))


# -- serial framing ---------------------------------------------------------------------------------------------
# Over a serial line the same datagrams travel SLIP-framed (RFC 1055): END ends a frame; END and ESC inside a
# frame are escaped. A receiver that starts mid-frame loses only that frame (its CRC fails).
SLIP_END, SLIP_ESC, SLIP_ESC_END, SLIP_ESC_ESC = 0xC0, 0xDB, 0xDC, 0xDD


def slip_encode(datagram: bytes) -> bytes:
    out = bytearray([SLIP_END])
    for b in datagram:
        if b == SLIP_END:
            out += bytes([SLIP_ESC, SLIP_ESC_END])
        elif b == SLIP_ESC:
            out += bytes([SLIP_ESC, SLIP_ESC_ESC])
        else:
            out.append(b)
    out.append(SLIP_END)
    return bytes(out)


class SlipDecoder:
    """Feed bytes as they arrive; get the complete frames back."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._esc = False

    def feed(self, data: bytes) -> list[bytes]:
        frames = []
        for b in data:
            if self._esc:
                self._buf.append(SLIP_END if b == SLIP_ESC_END else SLIP_ESC if b == SLIP_ESC_ESC else b)
                self._esc = False
            elif b == SLIP_ESC:
                self._esc = True
            elif b == SLIP_END:
                if self._buf:
                    frames.append(bytes(self._buf))
                    self._buf.clear()
            else:
                self._buf.append(b)
        return frames
