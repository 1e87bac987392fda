"""Real-time footing for a loop in its own process: pacing statistics, a timed hybrid sleep/spin clock, and the
process setup that keeps other work off the loop's CPU time.

Why each step of :func:`realtime_setup` (research/haptics.md; measured with ``studyctl bench servo``):

- CPU affinity: the loop stays on one core, its caches warm, never migrated mid-tick.
- SCHED_FIFO (root or CAP_SYS_NICE): no normal process preempts the loop. Threads the loop's process starts later
  (the safety watchdog, an SDK's own thread) *inherit* the policy: a helper thread at normal priority that takes the
  interpreter lock and is then preempted by the machine's other processes holds the loop off the lock for as long as
  the scheduler keeps it waiting (a priority inversion: on a loaded machine, milliseconds).
- ``mlockall``: the loop's pages stay in RAM (a page fault on a swapped or lazily mapped page costs a tick); only when
  the memory-lock limit allows the whole process, because a locked process whose new allocations exceed the limit
  would fail them.
- Timer slack 1 ns (``prctl``): a normal process's sleeps may end up to 50 µs late by default.
- Garbage collection frozen and disabled: a collection of the young generation can take milliseconds.

Each step is best effort; the report says which took effect, and why not (``warnings``), measured after the fact.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import gc
import math
import os
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from studyctl.engine.clock import RealClock

SPIN_S = 0.0003  # the hybrid wait sleeps until this long before a tick is due, then spins
# SCHED_FIFO priority of the loop: above every normal process, below the kernel's own threads at 99
FIFO_PRIORITY = 80
SWITCH_INTERVAL_S = 1e-4
THREAD_STACK = 512 * 1024  # stacks of threads started in a locked process (the watchdog needs little)
MLOCK_HEADROOM = 1 << 30  # lock memory only when the limit leaves this much room above what the process uses now


@dataclass(frozen=True)
class ServoTiming:
    """Pacing of a real-time loop: lateness of tick starts and period jitter, in microseconds."""

    ticks: int
    period_us: float
    late_us_p50: float
    late_us_p99: float
    late_us_max: float
    period_jitter_us_p50: float
    period_jitter_us_p99: float
    period_jitter_us_max: float
    overruns: int  # ticks that started more than one period late
    late_1ms: int = 0  # ticks that started more than 1 ms after they were due

    @classmethod
    def from_starts(cls, starts: np.ndarray, period_s: float, scheduled: np.ndarray | None = None) -> ServoTiming:
        """Timing from the tick start times (s) of a loop scheduled every ``period_s``.

        ``scheduled`` are the times each tick was due (default: the first start plus whole periods).
        """
        starts = np.asarray(starts, dtype=float)
        if len(starts) < 2:
            return cls(len(starts), period_s * 1e6, *([math.nan] * 6), 0)
        if scheduled is None:
            scheduled = starts[0] + period_s * np.arange(len(starts))
        late = (starts - np.asarray(scheduled, dtype=float)) * 1e6
        jitter = np.abs(np.diff(starts) - period_s) * 1e6
        return cls(
            ticks=len(starts),
            period_us=period_s * 1e6,
            late_us_p50=float(np.percentile(late, 50)),
            late_us_p99=float(np.percentile(late, 99)),
            late_us_max=float(late.max()),
            period_jitter_us_p50=float(np.percentile(jitter, 50)),
            period_jitter_us_p99=float(np.percentile(jitter, 99)),
            period_jitter_us_max=float(jitter.max()),
            overruns=int(np.sum(late > period_s * 1e6)),
            late_1ms=int(np.sum(late > 1000.0)),
        )

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


class TimedClock(RealClock):
    """A real clock with a hybrid sleep/spin wait that records when each tick actually started.

    The tick times go into preallocated arrays (no allocation per tick)."""

    def __init__(self, capacity: int = 1 << 20, spin_s: float = SPIN_S) -> None:
        super().__init__()
        self.starts = np.empty(capacity)
        self.due = np.empty(capacity)
        self.n = 0
        self.spin_s = spin_s

    def sleep_until(self, t: float) -> None:
        now = self.now
        remaining = t - now()
        if remaining > self.spin_s:
            time.sleep(remaining - self.spin_s)
        while now() < t:
            pass
        if self.n < len(self.starts):
            self.starts[self.n] = now()
            self.due[self.n] = t
            self.n += 1

    def timing(self, period_s: float) -> ServoTiming:
        """Lateness against each tick's due time and period jitter of the ticks recorded so far."""
        return ServoTiming.from_starts(self.starts[: self.n], period_s, self.due[: self.n])


@functools.cache
def _libc() -> Any:
    """The C library, looked up once. On Linux from the process's own symbols: ``ctypes.util.find_library`` runs
    ``ldconfig -p`` in a subprocess, which inside :func:`realtime_setup` was a child process at the loop's priority
    (traced: 20-68 ms of one servo process's setup at SCHED_FIFO held another servo loop off its CPU)."""
    try:
        lib = ctypes.CDLL(None, use_errno=True) if sys.platform.startswith("linux") else None
        if lib is None or not hasattr(lib, "mlockall"):
            name = ctypes.util.find_library("c")
            lib = ctypes.CDLL(name, use_errno=True) if name else None
    except OSError:
        lib = None
    return lib


def _memory_lock(report: dict[str, Any], warnings: list[str]) -> None:
    """mlockall(MCL_CURRENT | MCL_FUTURE) when the memory-lock limit leaves room for the whole process."""
    if not sys.platform.startswith("linux"):
        return
    import resource  # noqa: PLC0415

    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    if not _can_lock_ipc() and soft != resource.RLIM_INFINITY and soft < rss + MLOCK_HEADROOM:
        warnings.append(f"memory not locked: RLIMIT_MEMLOCK is {soft // 1024} KiB (raise it with `ulimit -l "
                        "unlimited`, or grant CAP_IPC_LOCK)")
        report["mlock"] = False
        return
    libc = _libc()
    if libc is None or libc.mlockall(1 | 2) != 0:  # MCL_CURRENT | MCL_FUTURE
        err = ctypes.get_errno() if libc is not None else 0
        warnings.append(f"memory not locked: mlockall failed ({os.strerror(err) if err else 'no libc'})")
        report["mlock"] = False
        return
    report["mlock"] = True
    # With every future page locked, a thread started later (the safety watchdog, at the trial's start) would fault
    # its whole default 8 MiB stack in at once: measured 1.5-2 ms, the trial's first tick late every time
    threading.stack_size(THREAD_STACK)
    report["thread_stack_kib"] = THREAD_STACK // 1024


def _can_lock_ipc() -> bool:
    """Whether this process holds CAP_IPC_LOCK (root has it), which lifts the memory-lock limit."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> 14 & 1)
    except (OSError, ValueError):
        pass
    return False


def memory_unlock() -> None:
    """Undo :func:`realtime_setup`'s memory lock (a servo process waiting for its next trial)."""
    libc = _libc() if sys.platform.startswith("linux") else None
    if libc is not None:
        libc.munlockall()


def _timer_slack(report: dict[str, Any]) -> None:
    libc = _libc() if sys.platform.startswith("linux") else None
    if libc is not None and libc.prctl(29, 1, 0, 0, 0) == 0:  # PR_SET_TIMERSLACK: 1 ns
        report["timer_slack_ns"] = 1


def realtime_setup(cpu: int | None = None, nice: int = -10, *, lock_memory: bool = True) -> dict[str, Any]:
    """Give this process the best real-time footing the OS allows; return what it actually got.

    Pins the process to one CPU (``cpu``, default :func:`least_held_cpu`), asks for SCHED_FIFO at
    :data:`FIFO_PRIORITY` (needs root or CAP_SYS_NICE; else lowers the nice value by ``-nice`` as far as permitted,
    with a warning), locks its memory, sets the timer slack to 1 ns, and freezes then disables the garbage collector.
    The report says what took effect (``sched``, ``priority``, ``nice``, ``cpus``, ``mlock``, ``gc``) and, under
    ``warnings``, what did not and how to get it.
    """
    report: dict[str, Any] = {}
    warnings: list[str] = []
    if hasattr(os, "sched_setaffinity"):
        try:
            allowed = sorted(os.sched_getaffinity(0))
            target = cpu if cpu is not None and cpu in allowed else least_held_cpu(allowed)
            os.sched_setaffinity(0, {target})
        except OSError as exc:
            warnings.append(f"not pinned to one CPU ({exc.strerror})")
        report["cpus"] = sorted(os.sched_getaffinity(0))
    # The slow steps first, at normal priority: locking memory, collecting garbage and looking up libc take tens of
    # milliseconds on a loaded machine, which at SCHED_FIFO would hold every normal process (and another servo
    # loop of the same priority) off this CPU for that long
    if lock_memory:
        _memory_lock(report, warnings)
    _timer_slack(report)
    # A helper thread holding the interpreter lock when the loop wakes is asked to drop it after this interval
    # (default 5 ms: a whole tick and more lost)
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    report["switch_interval_us"] = sys.getswitchinterval() * 1e6
    gc.collect()
    gc.freeze()  # everything allocated so far is never scanned again
    gc.disable()  # and nothing new is collected until the trial ends
    report["gc"] = "frozen+disabled"
    fifo = False
    if hasattr(os, "SCHED_FIFO"):
        try:
            # No SCHED_RESET_ON_FORK: threads started later (the safety watchdog, an SDK's thread) run at the loop's
            # priority, so none of them can be preempted by the machine's other processes while holding the
            # interpreter lock the loop waits for (see the module docstring)
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
            fifo = True
        except (OSError, PermissionError) as exc:
            warnings.append(f"no SCHED_FIFO ({exc.strerror or exc}): the loop shares its CPU with normal processes; "
                            "run as root or grant CAP_SYS_NICE (setcap cap_sys_nice+ep on the Python binary)")
    report["fifo"] = fifo
    if not fifo and nice:
        with contextlib.suppress(OSError):
            report["reniced"] = _renice(nice)
    if hasattr(os, "sched_getscheduler"):
        policy = os.sched_getscheduler(0)
        policy &= ~getattr(os, "SCHED_RESET_ON_FORK", 0)
        names = {getattr(os, n): n for n in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH", "SCHED_IDLE")
                 if hasattr(os, n)}
        report["sched"] = names.get(policy, str(policy))
        report["priority"] = os.sched_getparam(0).sched_priority
    report["nice"] = os.nice(0)
    if warnings:
        report["warnings"] = warnings
    return report


PF_KTHREAD = 0x00200000  # /proc/PID/stat flags: a kernel thread (its per-CPU FIFO threads are on every CPU alike)
_RT_POLICIES = frozenset({1, 2})  # SCHED_FIFO, SCHED_RR


def least_held_cpu(allowed: list[int], proc: str = "/proc") -> int:
    """The allowed CPU that the fewest other real-time loops are pinned to (the last one on a tie, as before).

    A loop pinned to a CPU at SCHED_FIFO shares it with any other loop pinned there at the same priority: a second
    session, or a bench or test beside a session, pinned like this one to the last CPU made both loops wait for each
    other's spin. Counted: user processes (not kernel threads) whose main thread runs SCHED_FIFO or SCHED_RR and may
    run on that CPU alone (``/proc/PID/stat``; their other threads are not read, which keeps the scan to a few
    milliseconds, done at normal priority). Best effort: two loops set up at the same moment can still pick the same
    CPU, and where ``/proc`` cannot be read this is the last allowed CPU."""
    held = dict.fromkeys(allowed, 0)
    me = os.getpid()
    try:
        entries = [e.name for e in os.scandir(proc) if e.name.isdigit() and int(e.name) != me]
    except OSError:
        entries = []
    for pid in entries:
        try:
            with open(f"{proc}/{pid}/stat", "rb") as fh:
                stat = fh.read()
            fields = stat[stat.rindex(b")") + 2:].split()  # after the command name, which may hold spaces
            if int(fields[6]) & PF_KTHREAD or int(fields[38]) not in _RT_POLICIES:  # flags (9th), policy (41st)
                continue
            cpus = os.sched_getaffinity(int(pid))
        except (OSError, ValueError, IndexError):  # gone meanwhile, or not ours to read
            continue
        if len(cpus) == 1 and (c := next(iter(cpus))) in held:
            held[c] += 1
    return min(allowed, key=lambda c: (held[c], -c))


def realtime_release(report: dict[str, Any]) -> None:
    """After a trial: back to normal scheduling, the collector back on, memory unlocked (a servo process between
    trials builds the next trial's plugins and reports this one: at SCHED_FIFO that work held every normal process,
    and another servo loop of the same priority, off its CPU)."""
    if report.get("fifo"):
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    if report.get("reniced"):
        with contextlib.suppress(OSError):
            _renice(-int(report["reniced"]))  # only undone as far as the OS lets an unprivileged process
    gc.enable()
    gc.unfreeze()
    if report.get("mlock"):
        memory_unlock()
        threading.stack_size(0)


def cpu_steal_ms(cpu: int | None) -> float | None:
    """Milliseconds the hypervisor has taken from CPU ``cpu`` since boot (``steal`` in /proc/stat, 10 ms steps), or
    None where unknown (not Linux, no such CPU, no cpu pinned).

    On a virtual machine the host stops a virtual CPU while it runs other work: for 1-13 ms at a time on the VM
    these figures were measured on, with no guest code running meanwhile (kernel trace: no event at all on that
    CPU), which no priority inside the guest prevents. A trial's difference of two readings says how much of that
    its loop's CPU suffered; it can under-count (a 13 ms stop of a spinning SCHED_FIFO loop was measured in a run
    that recorded no steal)."""
    if cpu is None:
        return None
    try:
        with open("/proc/stat") as f:
            for line in f:
                if line.startswith(f"cpu{cpu} "):
                    return int(line.split()[8]) * 1000.0 / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        pass
    return None


def _renice(delta: int) -> int:
    """Change this process's niceness by ``delta``; return the change actually made."""
    before = os.nice(0)
    return os.nice(delta) - before
