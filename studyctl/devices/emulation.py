"""Emulated hardware for rehearsals and tests: each hardware device plugin may name its emulator.

A device class with a classmethod ``emulate(params)`` — a context manager that starts the device's emulator
in its own process and yields the device parameters that reach it — can be rehearsed: ``studyctl run
--rehearse`` replaces the plan's hardware device by ``{"plugin": same name, "params": those params}`` for the
whole session and stops the emulator afterwards. :func:`start_emulator` runs an emulator module that prints
``READY <port>`` once it listens.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import threading
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from studyctl.closing import stop_process
from studyctl.errors import DeviceError, SessionError
from studyctl.plugins.registry import load_plugin

READY_TIMEOUT_S = 30.0


@contextlib.contextmanager
def start_emulator(module: str, args: Sequence[str] = (), *, what: str) -> Iterator[str]:
    """Run ``python -m module --port 0 ARGS`` in its own process; yield the address it printed (``READY ADDRESS``:
    a UDP port or a shared-memory name, then anything else it printed on that line, e.g. a world block's name);
    stop it on exit."""
    proc = subprocess.Popen([sys.executable, "-m", module, "--port", "0", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    line: list[str] = []
    reader = threading.Thread(target=lambda: line.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(READY_TIMEOUT_S)
    try:
        if not line or not line[0].startswith("READY "):
            proc.kill()
            err = proc.stderr.read().strip().splitlines()
            raise DeviceError(f"the {what} emulator did not start ({err[-1] if err else 'no output'})")
        yield " ".join(line[0].split()[1:])
    finally:
        stop_process(proc, 5.0)
        for stream in (proc.stdout, proc.stderr):
            stream.close()


def can_emulate(device: str) -> bool:
    return callable(getattr(load_plugin("device", device), "emulate", None))


def has_world(cls: type) -> bool:
    """Whether a device's emulator can put a virtual participant's hand in its world (``emulate(…, world=True)``)."""
    import inspect  # noqa: PLC0415

    emulate = getattr(cls, "emulate", None)
    return callable(emulate) and "world" in inspect.signature(emulate).parameters and getattr(cls, "WORLD", True)


@contextlib.contextmanager
def emulated(ref: Mapping[str, Any], *, world: bool = False) -> Iterator[dict[str, Any]]:
    """The device reference ``ref`` replaced by its emulator's, for the duration of the ``with`` block.

    ``world``: the emulator also opens its world for a virtual participant's hand (:mod:`studyctl.devices.world`);
    the reference then carries ``world: {kind, block}`` beside its params (``run --rehearse --virtual``)."""
    name = str(ref["plugin"])
    cls = load_plugin("device", name)
    if getattr(cls, "simulated", True):
        yield dict(ref)  # a simulated device needs no emulator
        return
    emulate = getattr(cls, "emulate", None)
    if not callable(emulate):
        raise SessionError(f"device {name} has no emulator, so it cannot be rehearsed; rehearse with its "
                           "simulated device (the protocol's devices.simulated) or run with the hardware")
    if world and not has_world(cls):
        raise SessionError(f"the emulator of device {name} has no world for a virtual participant's hand, so a "
                           "virtual participant cannot rehearse on it; rehearse with a person or a script (--rehearse "
                           "[--input FILE]), or simulate (--virtual without --rehearse)")
    with (emulate(dict(ref.get("params") or {}), world=True) if world else emulate(dict(ref.get("params") or {}))) \
            as params:
        params = dict(params)
        out: dict[str, Any] = {"plugin": name}
        if world:
            out["world"] = params.pop("world")
        out["params"] = params
        yield out
