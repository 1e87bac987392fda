"""A driver-board emulator that speaks :mod:`studyctl.devices.board_protocol` over UDP, as its own process.

Run it, then point a ``udp_driver_board`` device at the printed port::

    python -m studyctl.devices.board_emulator --port 0 --force 0.8
    READY 50123

It streams SENSOR packets (the force of ``--force`` or ``--profile`` through the A201 calibration and a
10-bit ADC) to the host that said HELLO, applies COMMANDs to modelled actuators (balloon and motor of
:mod:`studyctl.models.palpation_hw`), enforces its own output watchdog, and can misbehave on purpose for
tests: ``--adc-glitch START:DURATION`` (seconds after HELLO) sends an out-of-range ADC value,
``--silence-after S`` stops sending (a cable pulled), ``--log FILE`` writes every received command and
event as JSON lines.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import signal
import socket
import sys
import time
from dataclasses import dataclass, field

from studyctl.devices import board_protocol as bp
from studyctl.devices import world as w
from studyctl.devices.emulators import firmware_priority
from studyctl.errors import DatagramError
from studyctl.models.palpation_hw import A201, BalloonModel, VibrationMotorModel

FIRMWARE = 0x0100


def trapezoid(t: float, peak: float, rate: float, hold: float, rest: float) -> float:
    """A repeating trapezoid: ramp up at ``rate`` N/s to ``peak``, hold, ramp down, rest."""
    ramp = peak / rate if rate > 0 else 0.0
    period = 2 * ramp + hold + rest
    u = t % period if period > 0 else 0.0
    if u < ramp:
        return rate * u
    if u < ramp + hold:
        return peak
    if u < 2 * ramp + hold:
        return peak - rate * (u - ramp - hold)
    return 0.0


@dataclass
class Board:
    """The emulated board's state; :meth:`tick` and :meth:`receive` are all the firmware there is."""

    force_fn: object
    rate_hz: float = 50.0
    watchdog_ms: int = 250
    glitch: tuple[float, float] | None = None
    silence_after: float | None = None
    log_path: str | None = None
    world: object = None  # a world block (studyctl.devices.world): a virtual hand's force in, actuator output out
    host: tuple[str, int] | None = None
    start: float = field(default_factory=time.monotonic)
    hello_at: float | None = None
    last_command: float | None = None
    balloon: float = 0.0
    vibration: float = 0.0
    psi: float = 0.0
    speed: float = 0.0
    seq: int = 0
    rejected: int = 0
    dropped: int = 0
    status_flags: int = 0
    _last_dyn: float | None = None

    def now(self) -> float:
        return time.monotonic() - self.start

    def log(self, **entry) -> None:
        if self.log_path:
            with open(self.log_path, "a", encoding="utf-8") as fh:
                fh.write(json.dumps({"t": round(self.now(), 6), **entry}) + "\n")

    def receive(self, data: bytes, addr: tuple[str, int], sock: socket.socket) -> None:
        try:
            pkt = bp.decode(data)
        except DatagramError as exc:
            self.dropped += 1
            self.log(event="dropped", reason=str(exc))
            return
        now = self.now()
        if pkt.type == bp.HELLO:
            rate, wd = pkt.fields
            self.host, self.hello_at, self.last_command = addr, now, now
            self.status_flags = 0  # a new session starts clean (a previous one may have tripped the watchdog)
            self.rate_hz = float(rate) if rate else self.rate_hz
            self.watchdog_ms = int(wd) if wd else self.watchdog_ms
            self.seq += 1
            sock.sendto(
                bp.encode(
                    bp.STATUS, self.seq, FIRMWARE, A201.adc_bits, int(self.rate_hz), self.watchdog_ms, self.rejected
                ),
                addr,
            )
            self.log(event="hello", host=list(addr), rate_hz=self.rate_hz, watchdog_ms=self.watchdog_ms)
        elif pkt.type == bp.COMMAND:
            b, v = pkt.fields
            if b > 100 * bp.SCALE or v > 100 * bp.SCALE:
                self.rejected += 1
                self.status_flags |= bp.ST_REJECTED
                self.log(event="rejected", balloon=b, vibration=v)
                return
            self.balloon, self.vibration = b / bp.SCALE, v / bp.SCALE
            self.last_command = now
            self.status_flags &= ~bp.ST_WATCHDOG
            self.log(event="command", seq=pkt.seq, balloon_pct=self.balloon, vibration_pct=self.vibration)
        elif pkt.type in (bp.SAFE, bp.BYE):
            self.balloon = self.vibration = 0.0
            self.log(event="safe" if pkt.type == bp.SAFE else "bye")
            if pkt.type == bp.BYE:
                self.host = None
        else:
            self.dropped += 1

    def tick(self, sock: socket.socket) -> None:
        """Watchdog, actuator dynamics and one SENSOR packet."""
        now = self.now()
        if self.host is None:
            return
        if self.last_command is not None and (now - self.last_command) * 1000 > self.watchdog_ms:
            if not self.status_flags & bp.ST_WATCHDOG:
                self.log(event="watchdog_tripped", since_command_s=now - self.last_command)
            self.status_flags |= bp.ST_WATCHDOG
            self.balloon = self.vibration = 0.0
        dt = 0.0 if self._last_dyn is None else now - self._last_dyn
        self._last_dyn = now
        self.psi = BalloonModel().step(self.psi, self.balloon, dt)
        self.speed = VibrationMotorModel().step(self.speed, self.vibration, dt)
        world = self.world
        if world is not None:  # what the balloon and the motor deliver to the finger of a virtual hand
            hz, ms2 = VibrationMotorModel().output(self.speed)
            world[w.W_PSI], world[w.W_VIB_HZ], world[w.W_VIB_MS2] = self.psi, hz, ms2
            world[w.W_HEARTBEAT] += 1
        if self.silence_after is not None and self.hello_at is not None and now - self.hello_at >= self.silence_after:
            return
        force = float(world[w.W_FORCE_N]) if world is not None and world[w.W_ATTACHED] else float(self.force_fn(now))
        adc = A201.count_of_force(force)
        flags = self.status_flags
        since_hello = now - (self.hello_at or 0.0)
        if self.glitch and self.glitch[0] <= since_hello < self.glitch[0] + self.glitch[1]:
            adc = A201.adc_max + 77
            flags |= bp.ST_ADC_FAULT
        if self.psi >= BalloonModel().regulator_psi:
            flags |= bp.ST_REGULATOR
        self.seq += 1
        sock.sendto(
            bp.encode(
                bp.SENSOR,
                self.seq,
                int(now * 1e6) & 0xFFFFFFFF,
                adc,
                flags,
                int(round(self.balloon * bp.SCALE)),
                int(round(self.vibration * bp.SCALE)),
            ),
            self.host,
        )
        self.status_flags &= ~bp.ST_REJECTED


class PtyLink:
    """The board's end of a serial line: a pseudo-terminal whose other end (``path``) a host opens as a serial port;
    the datagrams travel SLIP-framed. ``recvfrom``/``sendto`` mimic the UDP socket so the board code is the same."""

    def __init__(self) -> None:
        import tty  # noqa: PLC0415

        self.master, slave = os.openpty()
        tty.setraw(slave)  # bytes pass unchanged (no echo, no line discipline)
        self.path = os.ttyname(slave)
        self._slave = slave  # kept open so the line exists before the host opens it
        os.set_blocking(self.master, False)
        self._decoder = bp.SlipDecoder()
        self._frames: list[bytes] = []

    def fileno(self) -> int:
        return self.master

    def recvfrom(self, size: int) -> tuple[bytes | None, tuple[str, int]]:
        if not self._frames:
            try:
                chunk = os.read(self.master, 4096)
            except (BlockingIOError, OSError):
                raise BlockingIOError from None
            if not chunk:
                raise BlockingIOError
            self._frames.extend(self._decoder.feed(chunk))
            if not self._frames:
                return None, ("serial", 0)
        return self._frames.pop(0), ("serial", 0)

    def sendto(self, data: bytes, addr: object) -> None:
        try:
            os.write(self.master, bp.slip_encode(data))
        except (BlockingIOError, OSError):
            pass  # nobody reads the line: as a real UART, bytes are lost

    def close(self) -> None:
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass


def _numbers(text: str, count: int) -> tuple[float, ...]:
    """``count`` colon-separated numbers; ValueError when there are more or fewer or one is not a number."""
    parts = text.split(":")
    if len(parts) != count:
        raise ValueError(text)
    return tuple(float(x) for x in parts)


def serve(args: argparse.Namespace) -> int:
    try:
        if args.profile and not args.profile.startswith("trapezoid:"):
            raise ValueError(args.profile)
        profile = _numbers(args.profile.removeprefix("trapezoid:"), 4) if args.profile else None
    except ValueError:
        print("Error: --profile must be trapezoid:PEAK_N:RATE_N_S:HOLD_S:REST_S", file=sys.stderr)
        return 2
    try:
        glitch = _numbers(args.adc_glitch, 2) if args.adc_glitch else None
    except ValueError:
        print("Error: --adc-glitch must be START_S:DURATION_S", file=sys.stderr)
        return 2
    if profile is not None:
        peak, rate, hold, rest = profile

        def force_fn(t: float) -> float:
            return trapezoid(t, peak, rate, hold, rest)
    else:
        const = float(args.force)

        def force_fn(t: float) -> float:
            return const

    firmware_priority()
    world_shm = world = None
    if args.world:
        world_shm, world = w.create_block()
    board = Board(
        force_fn,
        rate_hz=args.rate,
        watchdog_ms=args.watchdog_ms,
        glitch=glitch,
        silence_after=args.silence_after,
        log_path=args.log,
        world=world,
    )
    try:
        return _serve_board(board, args, world_shm)
    finally:
        board.world = world = None  # the block's buffer must have no views left before it is closed
        if world_shm is not None:
            world_shm.close()
            world_shm.unlink()


def _serve_board(board: Board, args: argparse.Namespace, world_shm) -> int:
    if args.serial:
        sock = PtyLink()
    else:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind((args.host, args.port))
        sock.setblocking(False)
    stop = {"flag": False}

    def _stop(*_):
        stop["flag"] = True

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    world_name = f" {world_shm.name}" if world_shm is not None else ""
    print(f"READY {sock.path if args.serial else sock.getsockname()[1]}{world_name}", flush=True)
    next_tick = board.now()
    # a board serves session after session (HELLO … BYE, then the next HELLO) until it is stopped
    deadline = board.now() + args.max_runtime if args.max_runtime > 0 else math.inf
    parent = os.getppid() if args.exit_with_parent else None
    while not stop["flag"] and board.now() < deadline:
        if parent is not None and os.getppid() != parent:
            break  # the rehearsal that started this board is gone
        timeout = max(0.0, next_tick - board.now())
        ready, _, _ = select.select([sock], [], [], timeout)
        if ready:
            while True:
                try:
                    data, addr = sock.recvfrom(2048)
                except BlockingIOError:
                    break
                if data is None:
                    continue  # a partial serial frame
                board.receive(data, addr, sock)
        if board.now() >= next_tick:
            board.tick(sock)
            period = 1.0 / board.rate_hz if board.rate_hz > 0 else 0.02
            next_tick += period
            if board.now() - next_tick > 10 * period:  # fell behind (suspended): resynchronise
                next_tick = board.now() + period
    board.log(event="exit", dropped=board.dropped, rejected=board.rejected)
    sock.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m studyctl.devices.board_emulator", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to bind (default loopback)")
    parser.add_argument("--port", type=int, default=0, help="UDP port (0: any free port, printed as READY <port>)")
    parser.add_argument("--serial", action="store_true",
                        help="a serial line instead of UDP: a pseudo-terminal, printed as READY /dev/pts/N")
    parser.add_argument("--rate", type=float, default=50.0, help="sensor packets per second before HELLO sets it")
    parser.add_argument("--watchdog-ms", type=int, default=250, help="output watchdog before HELLO sets it")
    parser.add_argument("--force", type=float, default=0.0, help="constant force on the sensor, N")
    parser.add_argument("--profile", help="trapezoid:PEAK_N:RATE_N_S:HOLD_S:REST_S (repeats)")
    parser.add_argument("--adc-glitch", help="START_S:DURATION_S (after HELLO) of out-of-range ADC values")
    parser.add_argument("--silence-after", type=float, help="stop sending sensor packets S seconds after HELLO")
    parser.add_argument("--exit-with-parent", action="store_true",
                        help="exit when the process that started the emulator ends (rehearsals)")
    parser.add_argument("--world", action="store_true",
                        help="also create a world block for a virtual hand (its name follows the port on READY): the "
                             "force on the sensor comes from the hand once it holds the forceps, and the balloon and "
                             "motor output go to it (run --rehearse --virtual)")
    parser.add_argument("--log", help="append received commands and events to this JSON-lines file")
    parser.add_argument("--max-runtime", type=float, default=0.0,
                        help="exit after this many seconds (default 0: run until stopped, session after session)")
    args = parser.parse_args(argv)
    if not math.isfinite(args.force):
        parser.error("--force must be finite")
    return serve(args)


if __name__ == "__main__":
    sys.exit(main())
