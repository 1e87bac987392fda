"""The board emulator started by hand serves session after session (it exited after each one, issue 18)."""

from __future__ import annotations

import functools
import time

import pytest
from polling import wait_for

from studyctl.devices.emulation import start_emulator
from studyctl.devices.udp_board import UdpDriverBoard

pytestmark = pytest.mark.slow


def _tick(board, t0):
    """One tick of a 50 Hz loop: the observation once a sample stamped after sensor_stale_s has come, else None."""
    obs = board.read(time.monotonic() - t0)
    board.write({"balloon_pct": 10.0, "vibration_pct": 0.0})
    return obs if obs.sample_t > board.limits.sensor_stale_s else None


def test_the_board_emulator_serves_one_session_after_another():
    with start_emulator("studyctl.devices.board_emulator", ["--force", "0.8"], what="board") as port:
        for _session in range(3):
            board = UdpDriverBoard({"port": int(port)})
            board.open()
            try:
                # The board keeps streaming in this session: fresh samples still arrive after the one that open()
                # waited for (read at ~0 s). Polled, not "age < sensor_stale_s after a 0.02 s sleep", which a loaded
                # machine's late sleep or emulator could break; a board that stopped sending never passes.
                obs = wait_for(functools.partial(_tick, board, time.monotonic()), timeout=10.0,
                               what="a fresh sample later in the session", interval=0.02)
                assert not obs.faults and obs.values["force_n"] == pytest.approx(0.8, abs=0.05)
            finally:
                board.close()
            time.sleep(0.3)  # between sessions: the board waits for the next HELLO


def test_a_virtual_hand_in_the_board_emulators_world_presses_the_sensor_and_feels_the_balloon():
    """``--world``: the hand's press reaches the host only through the emulated ADC and the adapter; the host's
    commands reach the hand only through the packets and the emulator's actuator models."""
    from studyctl.devices.world import embody  # noqa: PLC0415
    from studyctl.plugins.interfaces import Scene  # noqa: PLC0415

    class Spring(Scene):  # 0.5 N per mm pressed, anywhere: the phantom is not what this test checks
        name = "spring"

        @classmethod
        def build(cls, spec, placement, needs, rng):
            return cls()

        def sense(self, inputs):
            return {"force_n": 0.5 * max(float(inputs.get("depth_mm", 0.0)), 0.0)}

    with UdpDriverBoard.emulate({}, world=True) as params:
        world = params.pop("world")
        device = embody(UdpDriverBoard(params), world, Spring())
        device.open()
        try:
            def hold(inputs, command, seconds):
                t0 = time.monotonic()
                while time.monotonic() - t0 < seconds:
                    device.apply_input(inputs)
                    obs = device.read(time.monotonic() - t0)
                    device.write(command)
                    time.sleep(0.02)
                return obs, device.feedback()

            obs, felt = hold({"x_mm": 10, "y_mm": 10, "depth_mm": 0.0}, {"balloon_pct": 0.0}, 0.3)
            assert obs.values["force_n"] == pytest.approx(0.0, abs=0.05) and felt["balloon_psi"] < 0.5
            obs, felt = hold({"x_mm": 10, "y_mm": 10, "depth_mm": 4.0}, {"balloon_pct": 80.0, "vibration_pct": 60.0},
                             0.8)
            # 4 mm commanded; the wrist yields (0.5 mm/N at 0.5 N/mm: d = 4 / 1.25) so the tip sinks 3.2 mm:
            # 1.6 N through the 10-bit ADC
            assert obs.values["depth_mm"] == pytest.approx(3.2, abs=0.01)
            assert obs.values["force_n"] == pytest.approx(1.6, abs=0.08)
            assert felt["balloon_psi"] > 3.0 and felt["vibration_ms2"] > 1.0, felt
        finally:
            device.close()
