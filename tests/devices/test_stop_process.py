"""closing.stop_process: the one way an emulator or a browser child is ended (asked, then killed, always reaped)."""

from __future__ import annotations

import subprocess
import sys
import time

from studyctl.closing import stop_process


def _child(code: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"  # its signal handling is set before it is stopped
    return proc


def test_a_child_that_ends_on_sigterm_is_reaped_at_once():
    proc = _child("import time; print('ready', flush=True); time.sleep(60)")
    t0 = time.monotonic()
    stop_process(proc, 10.0)
    assert proc.returncode == -15  # ended by SIGTERM, not by the kill
    assert time.monotonic() - t0 < 10.0
    proc.stdout.close()


def test_a_child_that_ignores_sigterm_is_killed_after_the_timeout():
    proc = _child("import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('ready', flush=True); "
                  "time.sleep(60)")
    t0 = time.monotonic()
    stop_process(proc, 0.5)
    assert proc.returncode == -9
    assert time.monotonic() - t0 >= 0.5
    proc.stdout.close()


def test_a_child_that_has_ended_is_left_alone():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    stop_process(proc, 0.1)
    assert proc.returncode == 0
