"""What the hardware adapters share: their vendor SDK loaded on open (or studyctl's emulated stand-in), an
emulator process for rehearsals, and, for the 3-DoF force devices, the force limits and the force buffers.

The adapters differ in how they talk to their SDK (open, read, close); what is here is the same idea in each.
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Iterator, Mapping, Sequence
from types import ModuleType
from typing import Any, ClassVar

from studyctl.devices.base import ParamDevice
from studyctl.errors import DeviceError
from studyctl.plugins.interfaces import ChannelLimit, Channels, DeviceLimits
from studyctl.plugins.params import Param

FORCE_CHANNELS = ("fx_n", "fy_n", "fz_n")


def use_emulated_sdk(package: str, env: str, emulator: str) -> None:
    """Make ``import package`` find studyctl's stand-in (emulators/sdk) driving ``emulator`` in this process."""
    import os  # noqa: PLC0415
    import sys  # noqa: PLC0415

    from studyctl.devices.emulators import SDK_DIR  # noqa: PLC0415

    loaded = sys.modules.get(package)
    if loaded is not None and not getattr(loaded, "EMULATED", False):
        raise DeviceError(f"the real {package} is already loaded in this process; an emulated device needs its own")
    os.environ[env] = emulator
    if SDK_DIR not in sys.path:
        sys.path.insert(0, SDK_DIR)


def import_sdk(
    module: str, env: str, emulator: str, *, missing: str, no_library: str | None = None
) -> ModuleType:
    """Import a vendor SDK module when a device opens (never at studyctl's import), or studyctl's stand-in driving
    ``emulator`` (the running emulator's name, found through the environment variable ``env``).

    ``missing``: the error when the package is not installed (the install hint; the import error is appended);
    ``no_library``: when given, the error when the package is there but its native library is not (``{exc}`` is
    the loader's message)."""
    if emulator:
        use_emulated_sdk(module.split(".")[0], env, emulator)
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise DeviceError(f"{missing} ({exc})") from None
    except OSError as exc:  # bindings whose vendor library (libHD, libdhd) is absent fail at import
        if no_library is None:
            raise
        raise DeviceError(no_library.format(exc=exc)) from None


@contextlib.contextmanager
def run_emulator(
    module: str, args: Sequence[str], *, what: str, hang_after_s: float | None, hang_flag: str = "--hang-after"
) -> Iterator[str]:
    """Start the emulator ``python -m module args`` (it exits with this process) and yield the handle it printed
    (a shared-memory name, a port, a pseudo-terminal); ``hang_after_s`` (tests): it stops answering then."""
    from studyctl.devices.emulation import start_emulator  # noqa: PLC0415

    argv = [*args, "--exit-with-parent"]
    if hang_after_s is not None:
        argv += [hang_flag, str(hang_after_s)]
    with start_emulator(module, argv, what=what) as handle:
        yield handle


# Parameters every vendor adapter declares with the same meaning and range (each adapter lists them in its PARAMS)
SCALE_PARAM = Param("scale", 1.0, 1e-3, 100.0, source="device mm → scene mm")
EMULATOR_PARAM = Param("emulator", "", kind=str,
                       source="a running emulator's name (rehearsals, tests); empty: the device")


class ForceAdapter(ParamDevice):
    """A 3-DoF force device (Force Dimension, 3D Systems, Haply) reached through its vendor's Python SDK.

    A subclass names its SDK loader (``load_sdk``, imported on open so studyctl runs without it) and the model
    the shared-memory emulator (:mod:`studyctl.devices.emulators.shm_device`) plays; its ``setup`` calls
    :meth:`force_limits`."""

    simulated = False
    EMULATED_MODEL: ClassVar[str]  # shm_device --model
    EMULATED_WHAT: ClassVar[str]  # how the emulator's errors name the device
    # whether the emulator's world (a virtual participant's hand, studyctl.devices.world) fits this adapter's frames:
    # position, pen axis (a column of the wrist rotation) and button as this adapter reads them
    WORLD: ClassVar[bool] = False

    @staticmethod
    def load_sdk(emulator: str = "") -> Any:
        raise NotImplementedError

    @classmethod
    def check_installed(cls) -> None:
        """Raise DeviceError naming the extra to install when the vendor package is missing (before a session)."""
        cls.load_sdk()

    @classmethod
    @contextlib.contextmanager
    def emulate(cls, params: Mapping[str, Any], hang_after_s: float | None = None,
                world: bool = False) -> Iterator[dict[str, Any]]:
        """Start this model's emulator (its own process) and yield the params that drive it through the SDK's own
        API (a rehearsal's device). ``world`` (adapters with :attr:`WORLD`): also the emulator's world block for a
        virtual participant's hand, yielded as ``world: {kind, block}`` (:mod:`studyctl.devices.world`)."""
        if world and not cls.WORLD:
            raise DeviceError(f"the {cls.EMULATED_WHAT} emulator has no world for a virtual participant's hand")
        args = ["--model", cls.EMULATED_MODEL, *(["--world"] if world else [])]
        with run_emulator("studyctl.devices.emulators.shm_device", args, what=cls.EMULATED_WHAT,
                          hang_after_s=hang_after_s) as handle:
            name, _, block = handle.partition(" ")
            out: dict[str, Any] = {**dict(params), "emulator": name}
            if world:
                out["world"] = {"kind": "force3d", "block": block}
            yield out

    def force_limits(
        self, p: Mapping[str, Any], *, sensor_stale_s: float, max_rate_per_s: float | None = None
    ) -> None:
        """Set ``limits`` (each force channel within ±``max_force_n``, ramped over ``ramp_up_s``) and zeroed force
        buffers: ``_force`` (what goes to the SDK) and ``_feedback`` (what :meth:`feedback` reports)."""
        self.max_force_n = float(p["max_force_n"])
        self.limits = DeviceLimits(
            outputs=tuple(ChannelLimit(ch, -self.max_force_n, self.max_force_n, 0.0, max_rate_per_s, "N")
                          for ch in FORCE_CHANNELS),
            max_force_n=self.max_force_n, sensor_stale_s=sensor_stale_s, ramp_up_s=float(p["ramp_up_s"]),
        )
        self._force = [0.0, 0.0, 0.0]
        self._feedback = dict.fromkeys(FORCE_CHANNELS, 0.0)

    def store_force(self, command: Channels) -> list[float]:
        """Copy ``command``'s force into the SDK buffer (in place: no allocation in the 1 kHz loop) and the
        feedback; return the buffer."""
        f = self._force
        f[0], f[1], f[2] = command.get("fx_n", 0.0), command.get("fy_n", 0.0), command.get("fz_n", 0.0)
        fb = self._feedback
        fb["fx_n"], fb["fy_n"], fb["fz_n"] = f
        return f

    def feedback(self) -> dict[str, float]:
        return self._feedback
