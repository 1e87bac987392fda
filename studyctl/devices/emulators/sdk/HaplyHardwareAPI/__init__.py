"""Stand-in for ``HaplyHardwareAPI`` (Haply's Python API for the Inverse3) on studyctl's device emulator: the same
names as Haply's samples use (``detect_inverse3s``, ``SerialStream``, ``Inverse3.device_wakeup_dict``,
``Inverse3.end_effector_force``), positions in m and velocities in m/s in the device frame. It drives the emulator
named by ``STUDYCTL_HAPLY_EMULATOR``."""

from __future__ import annotations

import os

from studyctl.devices.emulators import shm_device as _emu

EMULATED = True
# where the emulator's origin lies in the Inverse3 frame (the workspace centre of Haply's position-control sample)
CENTRE_M = (0.0186, -0.153, 0.151)


def detect_inverse3s() -> list[str]:
    name = os.environ.get("STUDYCTL_HAPLY_EMULATOR")
    return [f"emulator:{name}"] if name else []


class SerialStream:
    def __init__(self, port: str) -> None:
        if not str(port).startswith("emulator:"):
            raise OSError(f"could not open port {port}")
        self.port = port
        self.shm, self.s = _emu.attach(port.split(":", 1)[1])
        self.state = {"s": self.s, "seen": (-1.0, 0.0)}

    def close(self) -> None:
        self.s[_emu.OPENED] = 0.0
        self.shm.close()


class Inverse3:
    def __init__(self, com_stream: SerialStream) -> None:
        self.com = com_stream

    def device_wakeup_dict(self) -> dict:
        s = self.com.s
        if s[_emu.OPENED] > 0:
            raise OSError("device busy: opened by another process")
        s[_emu.OPENED] = float(os.getpid())
        s[_emu.ENABLED] = 1.0
        s[_emu.WATCHDOG] = 80.0  # the firmware drops forces 10 ms after the last command
        return {"device_id": 3001, "device_model_number": 60, "hardware_version": 3, "firmware_version": 7}

    def end_effector_force(self, forces=None):
        s = self.com.s
        if not _emu.answering(self.com.state):
            raise TimeoutError("Inverse3: no response from the device")
        if forces is not None:
            s[_emu.CMD], s[_emu.CMD + 1], s[_emu.CMD + 2] = float(forces[0]), float(forces[1]), float(forces[2])
            s[_emu.CMD_SEQ] += 1.0
        pos = [float(s[_emu.POS + i]) + CENTRE_M[i] for i in range(3)]
        vel = [float(s[_emu.VEL + i]) for i in range(3)]
        return pos, vel
