"""The board emulator started by hand serves session after session (it exited after each one, issue 18)."""

from __future__ import annotations

import time

import pytest

from studyctl.devices.emulation import start_emulator
from studyctl.devices.udp_board import UdpDriverBoard

pytestmark = pytest.mark.slow


def test_the_board_emulator_serves_one_session_after_another():
    with start_emulator("studyctl.devices.board_emulator", ["--force", "0.8"], what="board") as port:
        for _session in range(3):
            board = UdpDriverBoard({"port": int(port)})
            board.open()
            try:
                t0 = time.monotonic()
                for _tick in range(10):  # 0.2 s of a 50 Hz loop
                    obs = board.read(time.monotonic() - t0)
                    board.write({"balloon_pct": 10.0, "vibration_pct": 0.0})
                    time.sleep(0.02)
                assert not obs.faults and obs.values["force_n"] == pytest.approx(0.8, abs=0.05)
                assert time.monotonic() - t0 - obs.sample_t < board.limits.sensor_stale_s
            finally:
                board.close()
            time.sleep(0.3)  # between sessions: the board waits for the next HELLO
