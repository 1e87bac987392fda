"""A haptic device emulated in its own process, shared with its SDK stand-in through shared memory.

Real haptic SDKs talk to their device over USB or a network link in a background thread of the vendor library;
reading the pose is a memory read and setting a force a memory write. This emulator does the same: it runs the
device's "firmware" loop at the device's communication rate in a separate process, publishes the handle state
into a shared block and applies the force written there, with the device's own protections: the force is
clamped to the device's maximum (a norm clamp, as the SDK's ``setMaxForce``), the handle stays inside the
workspace, and the firmware watchdog turns forces off when no force command arrives in time. The handle is
held by a modelled hand (a spring-damper to a slowly moving target), so the forces a controller renders move
it.

Run: ``python -m studyctl.devices.emulators.shm_device --model omega6 --port 0`` prints ``READY <id>`` where
``<id>`` names the shared block; ``--world`` also opens a world block for a virtual participant's hand (its name
follows on the READY line; :class:`studyctl.devices.world.ForceDeviceWorld`): while a hand holds the handle, the
modelled hand pulls towards where that hand wants it and its pen orientation and button are the wrist's, and the
force the device applies and where the handle is go back to the hand. ``--hang-after S`` stops the loop after
S seconds (a device that stops answering), ``--exit-with-parent`` ends it with the process that started it.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
import time
from dataclasses import dataclass
from multiprocessing import resource_tracker, shared_memory

import numpy as np

from studyctl.devices.emulators import firmware_priority

# Layout of the shared block (float64 slots).
HEARTBEAT, TIME, POS, VEL, ROT, BUTTON = 0, 1, 2, 5, 8, 17
CMD, CMD_SEQ, ENABLED, MAX_FORCE, WATCHDOG, APPLIED, OPENED, SATURATED, WD_TRIPS, RATE, MAX_NOMINAL = (
    18, 21, 22, 23, 24, 25, 28, 29, 30, 31, 32)
WORK_R, WORK_H, MODEL = 33, 34, 35
SLOTS = 40


@dataclass(frozen=True)
class Model:
    """What the emulator models of one device."""

    name: str
    code: int
    max_force_n: float  # peak force the device can render
    rate_hz: float  # communication (firmware loop) rate
    workspace_radius_m: float  # translational workspace: a cylinder of this radius …
    workspace_height_m: float  # … and this height, centred on the origin
    mass_kg: float  # moving mass at the handle


MODELS = {
    # omega.6: 12 N peak (CHAI3D driver), workspace ⌀160 × 110 mm (Force Dimension spec sheet), ~4 kHz USB
    "omega6": Model("omega.6", 1, 12.0, 4000.0, 0.080, 0.110, 0.20),
    # PHANToM Omni / Touch: 3.3 N peak (CHAI3D), workspace 160 × 120 × 70 mm (approx. a ⌀160 × 70 cylinder), 1 kHz
    "touch": Model("Touch", 2, 3.3, 1000.0, 0.080, 0.070, 0.045),
    # Haply Inverse3: CHOSEN, not from a spec sheet we could read: ~10 N peak, a ⌀240 × 160 mm cylinder, 1 kHz
    "inverse3": Model("Inverse3", 3, 10.0, 1000.0, 0.120, 0.160, 0.15),
}


def attach(name: str) -> tuple[shared_memory.SharedMemory, np.ndarray]:
    """Open the shared block of a running emulator (raises FileNotFoundError when there is none)."""
    shm = shared_memory.SharedMemory(name=name)
    # Python < 3.13 registers an attached block with this process's resource tracker, which would unlink the
    # emulator's block when this process ends; the emulator owns it.
    with contextlib.suppress(Exception):
        resource_tracker.unregister(shm._name, "shared_memory")  # noqa: SLF001
    return shm, np.ndarray((SLOTS,), dtype=np.float64, buffer=shm.buf)


STALE_S = 0.25  # no heartbeat from the emulator for this long: the SDK reports a communication error


def answering(state: dict) -> bool:
    """Whether the emulator behind a client's ``state`` (``{"s": block, "seen": (heartbeat, when)}``) still answers:
    its heartbeat moved within :data:`STALE_S`. Updates ``state["seen"]``."""
    beat = float(state["s"][HEARTBEAT])
    last, since = state["seen"]
    now = time.monotonic()
    if beat != last:
        state["seen"] = (beat, now)
        return True
    return now - since <= STALE_S


def hand_target(t: float) -> tuple[float, float, float]:
    """Where the modelled hand holds the handle: a slow figure in the workspace (m)."""
    return 0.02 * math.sin(0.5 * t), 0.015 * math.sin(0.7 * t), 0.01 * math.sin(0.3 * t)


def run(model: Model, name: str | None, hang_after: float | None, exit_with_parent: bool, world: bool = False) -> int:
    shm = shared_memory.SharedMemory(create=True, size=SLOTS * 8, name=name)
    wshm = w = None
    if world:
        from studyctl.devices import world as _world  # noqa: PLC0415

        wshm, w = _world.create_block(_world.FORCE_WORLD_SLOTS)
        w[_world.F_ROT:_world.F_ROT + 9] = (1, 0, 0, 0, 1, 0, 0, 0, 1)
    s = np.ndarray((SLOTS,), dtype=np.float64, buffer=shm.buf)
    s[:] = 0.0
    s[ROT:ROT + 9] = (1, 0, 0, 0, 1, 0, 0, 0, 1)
    s[MAX_FORCE] = s[MAX_NOMINAL] = model.max_force_n
    s[RATE] = model.rate_hz
    s[WORK_R], s[WORK_H], s[MODEL] = model.workspace_radius_m, model.workspace_height_m, model.code
    stop = {"flag": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(flag=True))
    signal.signal(signal.SIGINT, lambda *_: stop.update(flag=True))
    firmware_priority()
    print(f"READY {shm.name}" + (f" {wshm.name}" if wshm is not None else ""), flush=True)
    parent = os.getppid() if exit_with_parent else None
    period = 1.0 / model.rate_hz
    k_hand, b_hand = 300.0, 8.0  # N/m, N·s/m: a relaxed grip
    pos = np.zeros(3)
    vel = np.zeros(3)
    t0 = time.perf_counter()
    next_t = t0
    last_seq, last_cmd_t = -1.0, t0
    n = 0
    try:
        while not stop["flag"]:
            now = time.perf_counter()
            t = now - t0
            if hang_after is not None and t >= hang_after:
                while not stop["flag"]:  # the device stops answering: no heartbeat, no state
                    time.sleep(0.05)
                break
            if parent is not None and n % 512 == 0 and os.getppid() != parent:
                break
            seq = s[CMD_SEQ]
            if seq != last_seq:
                last_seq, last_cmd_t = seq, now
            watchdog_s = s[WATCHDOG] * 125e-6
            force = np.zeros(3)
            if s[ENABLED] > 0 and s[OPENED] > 0:
                if watchdog_s > 0 and now - last_cmd_t > watchdog_s:
                    if s[ENABLED] == 1.0:
                        s[WD_TRIPS] += 1
                    s[ENABLED] = 2.0  # forces off, brakes on, until the next enableForce
                else:
                    force = np.array(s[CMD:CMD + 3], dtype=float)
                    if not np.all(np.isfinite(force)):
                        force[:] = 0.0
                    limit = min(s[MAX_FORCE], model.max_force_n)
                    norm = float(np.linalg.norm(force))
                    s[SATURATED] = 1.0 if norm > limit else 0.0
                    if norm > limit:
                        force *= limit / norm
            s[APPLIED:APPLIED + 3] = force
            if w is not None and w[_world.F_ATTACHED] > 0:  # a virtual participant's hand holds the handle
                target = np.array(w[_world.F_TARGET:_world.F_TARGET + 3])
                s[ROT:ROT + 9] = w[_world.F_ROT:_world.F_ROT + 9]  # the passive wrist's encoders
                s[BUTTON] = w[_world.F_BUTTON]
            else:
                target = np.array(hand_target(t))
            braked = s[ENABLED] == 2.0
            acc = (force - k_hand * (pos - target) - (b_hand + (30.0 if braked else 0.0)) * vel) / model.mass_kg
            vel += acc * period
            pos += vel * period
            r = math.hypot(pos[0], pos[1])
            if r > model.workspace_radius_m:  # the mechanical stops
                pos[:2] *= model.workspace_radius_m / r
                vel[:2] = 0.0
            half = model.workspace_height_m / 2
            if abs(pos[2]) > half:
                pos[2] = math.copysign(half, pos[2])
                vel[2] = 0.0
            s[POS:POS + 3] = pos
            s[VEL:VEL + 3] = vel
            s[TIME] = t
            n += 1
            s[HEARTBEAT] = n
            if w is not None:  # what the hand feels: the force really applied, where the handle really is
                w[_world.F_FORCE:_world.F_FORCE + 3] = force
                w[_world.F_POS:_world.F_POS + 3] = pos
                w[_world.F_HEARTBEAT] = n
            next_t += period
            delay = next_t - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.05:
                next_t = time.perf_counter()  # fell behind (machine busy): resynchronise
    finally:
        shm.close()
        shm.unlink()
        if wshm is not None:
            wshm.close()
            wshm.unlink()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studyctl.devices.emulators.shm_device",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--model", choices=sorted(MODELS), default="omega6")
    parser.add_argument("--port", default="0", help="the shared block's name (0: a new unique name)")
    parser.add_argument("--hang-after", type=float, help="stop answering after S seconds")
    parser.add_argument("--exit-with-parent", action="store_true")
    parser.add_argument("--world", action="store_true", help="also open a world block for a virtual hand")
    args = parser.parse_args(argv)
    name = None if args.port in ("0", "") else args.port
    return run(MODELS[args.model], name, args.hang_after, args.exit_with_parent, args.world)


if __name__ == "__main__":
    sys.exit(main())
