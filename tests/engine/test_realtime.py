"""The servo process's real-time footing (studyctl.engine.realtime): what runs at SCHED_FIFO, and what does not."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

# Run in a process of its own: the setup pins the process to one CPU and raises its priority.
_PROBE = r"""
import gc, json, os, subprocess
from studyctl.engine import realtime

def policy():
    return os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)

seen = {"collect": [], "spawned": []}
collect = gc.collect
def watched_collect(*a):
    seen["collect"].append(policy())
    return collect(*a)
gc.collect = watched_collect
popen_init = subprocess.Popen.__init__
def watched_popen(self, args, *a, **kw):
    seen["spawned"].append([str(x) for x in args] if isinstance(args, (list, tuple)) else str(args))
    return popen_init(self, args, *a, **kw)
subprocess.Popen.__init__ = watched_popen
report = realtime.realtime_setup()
during = policy()
realtime.realtime_release(report)
print(json.dumps({"report": report, "collect": seen["collect"], "spawned": seen["spawned"], "during": during,
                  "after": policy(), "fifo": os.SCHED_FIFO, "other": os.SCHED_OTHER, "gc": gc.isenabled()}))
"""


@pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="POSIX scheduling")
def test_the_slow_setup_runs_at_normal_priority_and_the_trial_end_returns_to_it():
    """Traced on the loaded VM: a servo process's setup (gc.collect, mlockall, and ``find_library('c')``, which runs
    ``ldconfig`` in a child process) ran at SCHED_FIFO 80 and held another servo loop on the same CPU off it for
    20-68 ms; between trials the process stayed at SCHED_FIFO while building the next trial. Now the slow steps come
    before the priority is raised, nothing is spawned, and the release returns the process to SCHED_OTHER."""
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["collect"] and set(got["collect"]) == {got["other"]}, got  # the collection before SCHED_FIFO
    assert got["spawned"] == [], got  # no ldconfig (or anything else) started by the setup
    assert got["report"]["gc"] == "frozen+disabled" and got["gc"]  # and the collector back on after the release
    if not got["report"]["fifo"]:
        pytest.skip("SCHED_FIFO not permitted here (needs root or CAP_SYS_NICE)")
    assert got["during"] == got["fifo"] and got["report"]["sched"] == "SCHED_FIFO"
    assert got["after"] == got["other"]


# A loop of another process pinned to one CPU, blocked on its stdin (no CPU used); "fifo" at SCHED_FIFO 1.
_HOLDER = r"""
import os, sys
os.sched_setaffinity(0, {int(sys.argv[1])})
if sys.argv[2] == "fifo":
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
print("ready", flush=True)
sys.stdin.read()
"""


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs CPU affinity and two CPUs")
def test_a_servo_loop_avoids_a_cpu_another_real_time_loop_is_pinned_to():
    """Every servo process pinned itself to the last allowed CPU, so two sessions (or a test or bench beside a
    session) ran their SCHED_FIFO loops at the same priority on one CPU, each waiting for the other's spin. Now the
    setup picks the CPU the fewest other real-time loops are pinned to. Three SCHED_FIFO holders on the last CPU and
    three normal-priority ones pinned to the first (which must not count): the setup pins to the first (on the old
    code: the last). Three, not one: other engineers' servo loops on this shared machine may hold a CPU meanwhile."""
    allowed = sorted(os.sched_getaffinity(0))
    first, last = allowed[0], allowed[-1]
    holders = [subprocess.Popen([sys.executable, "-c", _HOLDER, str(cpu), policy], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
               for cpu, policy in [(last, "fifo")] * 3 + [(first, "other")] * 3]
    try:
        for h in holders:
            line = h.stdout.readline()
            if line.strip() != "ready":
                h.wait(timeout=10)
                if "Operation not permitted" in h.stderr.read():
                    pytest.skip("SCHED_FIFO not permitted here (needs root or CAP_SYS_NICE)")
                raise AssertionError(f"holder did not start: {line!r}")
        out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        assert json.loads(out.stdout)["report"]["cpus"] == [first]
    finally:
        for h in holders:
            h.stdin.close()
            h.wait(timeout=10)
