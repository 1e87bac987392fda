"""The physical world around emulated hardware, for a virtual participant's rehearsal (``run --rehearse --virtual``).

With a person the world is real: a hand presses the sensorised forceps into the phantom and feels the balloon. In a
virtual rehearsal the virtual participant acts on the *emulated hardware* instead of the simulated device, so the
emulator needs what a hand and a phantom would do to it. An emulator started with a world owns a small shared block:
the hand's side (:class:`EmbodiedDevice`, in the servo process) writes the physical input - for the palpation driver
board the force on the forceps' sensor, from the trial's phantom at the hand's pose - and reads what the actuators
physically deliver (balloon pressure, vibration), which the emulator's firmware computes from the commands it got over
the board's own wire protocol. The device adapter in between is the real one, unchanged: the sensor reaches the
controller through the ADC, the packets and the adapter's calibration; the controller's commands reach the hand through
the adapter, the packets and the emulator's actuator models. So a broken adapter, controller or emulator shows up in
the virtual participant's results exactly as it would with a person.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from dataclasses import replace
from multiprocessing import resource_tracker, shared_memory
from typing import Any

import numpy as np

from studyctl.errors import DeviceError
from studyctl.plugins.interfaces import Channels, Device, Observation, Scene

# Layout of a palpation board's world block (float64 slots): written by the emulator …
W_HEARTBEAT, W_PSI, W_VIB_HZ, W_VIB_MS2 = 0, 1, 2, 3
# … and by the hand: ATTACHED = 1 once a hand holds the forceps (the emulator then stops using its --force profile)
W_ATTACHED, W_FORCE_N = 4, 5
WORLD_SLOTS = 8


def create_block(slots: int = WORLD_SLOTS) -> tuple[shared_memory.SharedMemory, np.ndarray]:
    """A new zeroed world block (the emulator's side; it unlinks it when it exits)."""
    shm = shared_memory.SharedMemory(create=True, size=slots * 8)
    block = np.ndarray((slots,), dtype=np.float64, buffer=shm.buf)
    block[:] = 0.0
    return shm, block


def attach_block(name: str, slots: int = WORLD_SLOTS) -> tuple[shared_memory.SharedMemory, np.ndarray]:
    """Open a running emulator's world block (the hand's side)."""
    try:
        shm = shared_memory.SharedMemory(name=name)
    except FileNotFoundError:
        raise DeviceError(f"the emulator's world block {name!r} is gone (the emulator ended); start the rehearsal "
                          "again") from None
    # Python < 3.13 registers an attached block with this process's resource tracker, which would unlink the
    # emulator's block when this process ends; the emulator owns it.
    with contextlib.suppress(Exception):
        resource_tracker.unregister(shm._name, "shared_memory")  # noqa: SLF001
    return shm, np.ndarray((slots,), dtype=np.float64, buffer=shm.buf)


class _SharedWorld:
    """A world block this process attached to: :meth:`close` lets the hand go, then detaches (``block`` becomes a
    private zero array, so a late write after close lands nowhere instead of in freed shared memory)."""

    SLOTS = WORLD_SLOTS

    def attach(self, block: str) -> None:
        self._shm, self.block = attach_block(block, self.SLOTS)

    def release(self) -> None:
        """The hand lets go (each world says what that means on its block)."""

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.release()
        self.block = np.zeros(self.SLOTS)
        self._shm.close()


class PalpationBoardWorld(_SharedWorld):
    """A hand holding the seed-000 forceps over the trial's sponge phantom, on the board emulator's world block.

    :meth:`touch` takes the virtual participant's inputs (``x_mm``, ``y_mm``, commanded ``depth_mm``), lets the
    forceps' wrist yield as the simulated device does (:func:`~studyctl.devices.palpation.forceps_contact`) and puts
    the resulting force on the emulated sensor; :meth:`feel` is what the balloon and the motor deliver to the finger.
    """

    kind = "palpation_board"

    def __init__(self, block: str, scene: Scene | None, params: Mapping[str, Any] | None = None) -> None:
        from studyctl.devices.palpation import SimulatedPalpationDevice  # noqa: PLC0415

        defaults = {p.name: p.default for p in SimulatedPalpationDevice.PARAMS}
        self.compliance = float((params or {}).get("instrument_compliance_mm_per_n",
                                                   defaults["instrument_compliance_mm_per_n"]))
        self.scene = scene
        self.attach(block)
        self._pose = {"probe_x_mm": -1.0, "probe_y_mm": -1.0, "depth_mm": 0.0}

    def touch(self, inputs: Channels) -> None:
        from studyctl.devices.palpation import forceps_contact  # noqa: PLC0415

        x, y = float(inputs.get("x_mm", -1.0)), float(inputs.get("y_mm", -1.0))
        depth = float(inputs.get("depth_mm", 0.0))
        force = 0.0
        if self.scene is not None:
            depth, force = forceps_contact(self.scene, x, y, depth, self.compliance)
        self.block[W_FORCE_N] = force
        self.block[W_ATTACHED] = 1.0
        self._pose = {"probe_x_mm": x, "probe_y_mm": y, "depth_mm": depth}

    def pose(self) -> dict[str, float]:
        """Where the tip really is (what the endoscope shows): logged with the samples, drawn in the view."""
        return self._pose

    def feel(self) -> dict[str, float]:
        b = self.block
        return {"balloon_psi": float(b[W_PSI]), "vibration_hz": float(b[W_VIB_HZ]),
                "vibration_ms2": float(b[W_VIB_MS2])}

    def release(self) -> None:
        """The hand lets go: nothing presses on the sensor."""
        self.block[W_FORCE_N] = 0.0


# Layout of a 3-DoF force device's world block (float64 slots; emulators/shm_device --world): written by the emulator …
F_HEARTBEAT, F_FORCE, F_POS = 0, 1, 4  # the force the device applied (N), the handle's position (m), device frame
# … and by the hand: ATTACHED = 1 while it holds the handle, where it pulls the handle (m), the wrist's rotation
# (row-major 3 × 3) and the button
F_ATTACHED, F_TARGET, F_ROT, F_BUTTON = 7, 8, 11, 20
FORCE_WORLD_SLOTS = 24


class ForceDeviceWorld(_SharedWorld):
    """A hand holding a 3-DoF force device's handle (omega.6 class), on its emulator's world block.

    :meth:`touch` takes the virtual participant's inputs as it gives them to the simulated device (``x_mm``…: where
    the hand wants the handle, in scene mm; the pen axis ``dir_x``…; ``button``) and turns them into the device's
    frame with the adapter's own ``scale``, ``offset_mm`` and ``pen_axis``: the emulator's modelled hand pulls the
    handle there, against the force the controller renders through the SDK. :meth:`feel` is that force as the device
    applied it (after its own clamp and watchdog) and where the handle is, in scene mm. Nothing here reaches the
    controller: it reads the encoders through the SDK, as with a person.
    """

    kind = "force3d"
    SLOTS = FORCE_WORLD_SLOTS

    def __init__(self, block: str, scene: Scene | None, params: Mapping[str, Any] | None = None) -> None:
        p = dict(params or {})
        self.scale = float(p.get("scale", 1.0))
        self.offset = tuple(float(v) for v in p.get("offset_mm", (0.0, 0.0, 0.0)))
        axis = str(p.get("pen_axis", "-x"))
        self.col = "xyz".index(axis[-1])
        self.sign = -1.0 if axis.startswith("-") else 1.0
        self.scene = scene
        self.attach(block)
        self._feel = {"fx_n": 0.0, "fy_n": 0.0, "fz_n": 0.0, "x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0}

    def touch(self, inputs: Channels) -> None:
        b, k, o = self.block, 1.0 / (1000.0 * self.scale), self.offset
        x = inputs.get("x_mm")
        if x is not None:
            b[F_TARGET] = (float(x) - o[0]) * k
            b[F_TARGET + 1] = (float(inputs.get("y_mm", o[1])) - o[1]) * k
            b[F_TARGET + 2] = (float(inputs.get("z_mm", o[2])) - o[2]) * k
            b[F_ATTACHED] = 1.0
        d = inputs.get("dir_x")
        if d is not None:
            b[F_ROT:F_ROT + 9] = self._frame((float(d), float(inputs.get("dir_y", 0.0)),
                                              float(inputs.get("dir_z", 0.0))))
        button = inputs.get("button")
        if button is not None:
            b[F_BUTTON] = 1.0 if button >= 0.5 else 0.0

    def _frame(self, d: tuple[float, float, float]) -> np.ndarray:
        """A wrist rotation whose ``pen_axis`` column (with its sign) is the pen direction ``d``."""
        v = np.asarray(d, dtype=float)
        n = float(np.linalg.norm(v))
        v = v / n if n > 0 and np.isfinite(n) else np.array([0.0, 0.0, -1.0])
        helper = np.array([0.0, 0.0, 1.0]) if abs(v[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        a = np.cross(v, helper)
        a /= np.linalg.norm(a)
        c = np.cross(v, a)
        cols = [a, c]
        rot = np.empty((3, 3))
        rot[:, self.col] = self.sign * v
        for j in range(3):
            if j != self.col:
                rot[:, j] = cols.pop(0)
        if np.linalg.det(rot) < 0:  # a proper rotation
            j = next(j for j in range(3) if j != self.col)
            rot[:, j] *= -1.0
        return rot.reshape(9)

    def pose(self) -> dict[str, float]:
        return {}  # the encoders report the handle's pose through the SDK

    def feel(self) -> dict[str, float]:
        b, k, o, f = self.block, 1000.0 * self.scale, self.offset, self._feel
        f["fx_n"], f["fy_n"], f["fz_n"] = float(b[F_FORCE]), float(b[F_FORCE + 1]), float(b[F_FORCE + 2])
        f["x_mm"] = o[0] + k * float(b[F_POS])
        f["y_mm"] = o[1] + k * float(b[F_POS + 1])
        f["z_mm"] = o[2] + k * float(b[F_POS + 2])
        return f

    def release(self) -> None:
        """The hand lets go: the emulator's own modelled hand holds the handle again."""
        self.block[F_ATTACHED] = 0.0


WORLDS = {PalpationBoardWorld.kind: PalpationBoardWorld, ForceDeviceWorld.kind: ForceDeviceWorld}


class EmbodiedDevice(Device):
    """A hardware adapter on its emulator, with a virtual participant's hand in the emulated world.

    Everything the loop reads and writes goes through ``inner`` (the real adapter); only the participant's
    inputs (``apply_input``, a no-op on hardware) and what the actuators deliver to the hand (``feedback``) go
    through the world.
    """

    simulated = False

    def __init__(self, inner: Device, world: Any) -> None:
        super().__init__(inner.params, inner.scene, inner.rng)
        self.inner = inner
        self.world = world
        self.name = inner.name
        self.limits = inner.limits

    def open(self) -> None:
        self.world.release()
        self.inner.open()

    def close(self) -> None:
        try:
            self.world.release()
        finally:
            self.inner.close()

    def apply_input(self, inputs: Channels) -> None:
        self.world.touch(inputs)

    def read(self, t: float) -> Observation:
        obs = self.inner.read(t)
        return replace(obs, values={**obs.values, **self.world.pose()})

    def write(self, command: Channels) -> None:
        self.inner.write(command)

    def feedback(self) -> dict[str, float]:
        return {**self.inner.feedback(), **self.world.feel()}

    def identity(self) -> dict[str, Any]:
        ident = getattr(self.inner, "identity", None)
        return {**(dict(ident()) if callable(ident) else {}), "world": self.world.kind}


def embody(device: Device, world_ref: Mapping[str, Any], scene: Scene | None) -> EmbodiedDevice:
    """``device`` (an adapter connected to its emulator) with a hand in the emulator's world ``world_ref``
    (``{"kind": …, "block": …}``, from :func:`studyctl.devices.emulation.emulated` with ``world=True``)."""
    kind = str(world_ref.get("kind"))
    if kind not in WORLDS:
        raise DeviceError(f"unknown emulator world {kind!r}; known: {', '.join(sorted(WORLDS))}")
    # the world reads the adapter's own frame parameters (scale, offset, pen axis) beside its own
    params = {**dict(getattr(device, "params", None) or {}), **dict(world_ref.get("params") or {})}
    return EmbodiedDevice(device, WORLDS[kind](str(world_ref["block"]), scene, params))
