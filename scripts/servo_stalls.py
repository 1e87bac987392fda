"""Why does the servo loop miss ticks here? Run the `studyctl bench servo` loop once with the kernel tracing its CPU,
and name the cause of every late tick.

    sudo python scripts/servo_stalls.py [--seconds 10] [--json]

Needs root and tracefs (/sys/kernel/tracing; `mount -t tracefs none /sys/kernel/tracing`). It runs the bench's loop
(needle_hybrid ESG on sim_force3d, 1 kHz, the servo process's real-time setup) in a forked servo child that records,
per tick, when it was due, when its sleep ended and when it started; meanwhile a CPU hog keeps the other core busy (as
the bench) and ftrace records the loop CPU's context switches, wake-ups and interrupts on the same monotonic clock.

Each burst of late ticks (> 1 ms) is put in one class:

- ``cpu silent``: the loop's CPU produced no trace event at all (no switch, no interrupt, not even the timer
  interrupt that ends the loop's sleep) for most of the delay: no guest code ran on that virtual CPU, i.e. the
  hypervisor had stopped it. No scheduling setting inside the guest can prevent that;
- ``preempted``: the loop was switched out while runnable (names what ran);
- ``wakeup latency``: the loop was woken on time but ran > 0.3 ms later (another task in a non-preemptible kernel
  section: PREEMPT_NONE kernels);
- ``other``: none of these (the loop's own work took too long, e.g. a page fault or a slow tick).

The tracing settings it changes (clock, CPU mask, buffer size, events) are put back at the end. Run it on a quiet
machine of one's own: the trace buffer is the kernel's, shared with anyone tracing at the same time.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import re
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np

TRACE = Path("/sys/kernel/tracing")
EVENTS = ("sched/sched_switch", "sched/sched_wakeup", "irq_vectors/local_timer_entry", "irq/irq_handler_entry",
          "irq/softirq_entry")
LINE = re.compile(r"^\s*(.+?)-(\d+)\s+\[(\d+)\]\s+\S+\s+(\d+\.\d+):\s+(\w+):\s*(.*)$")


def _write(name: str, value: str) -> None:
    (TRACE / name).write_text(value)


def _steal_ms(cpu: int) -> float:
    from studyctl.engine.realtime import cpu_steal_ms

    return cpu_steal_ms(cpu) or 0.0


def _child(inbox, outbox, parent_pid: int, seconds: float, cpu: int, ticks_file: str) -> None:
    """The servo child of a bench trial, with a clock that also keeps its per-tick record."""
    import studyctl.engine.servo_child as servo_child
    from studyctl.bench.needle import _scenario
    from studyctl.bench.servo import _SCENE, RATE_HZ
    from studyctl.engine.realtime import TimedClock
    from studyctl.engine.servo import ServoSpec
    from studyctl.plugins.interfaces import TrialInfo

    class RecordingClock(TimedClock):
        def __init__(self, capacity: int = 1 << 20) -> None:
            super().__init__(capacity)
            self.woke = np.empty(capacity)

        def sleep_until(self, t: float) -> None:
            remaining = t - self.now()
            if remaining > self.spin_s:
                time.sleep(remaining - self.spin_s)
            if self.n < len(self.woke):
                self.woke[self.n] = self.now()
            super().sleep_until(t)  # spins the rest and records the start

        def timing(self, period_s: float):
            o, n = self._origin, self.n
            np.savez(ticks_file, due=self.due[:n] + o, woke=self.woke[:n] + o, starts=self.starts[:n] + o)
            return super().timing(period_s)

    servo_child.TimedClock = RecordingClock
    spec = ServoSpec(info=TrialInfo("ESG", seconds, RATE_HZ, "none"), device="sim_force3d",
                     device_params={"device_class": "omega6"}, controller="needle_hybrid",
                     controller_params=_scenario("ESG"), scene=_SCENE["scene"], scene_placement=_SCENE["placement"],
                     scene_needs=_SCENE["needs"], seed=2, cpu=cpu)
    servo_child.widen_pipe(outbox)
    servo_child.run_one(spec, 1, inbox, outbox, parent_pid)


def _hog(cpu: int, stop) -> None:
    os.sched_setaffinity(0, {cpu})
    x = 0
    while not stop.is_set():
        for i in range(20000):
            x = (x + i * i) % 1_000_003


def record(seconds: float, cpu: int, out_dir: Path) -> dict:
    """Run the traced trial; return its servo_timing payload, steal and load, leaving trace.txt and ticks.npz."""
    from studyctl.bench import busy_python

    ctx = mp.get_context("fork")
    stop = ctx.Event()
    hog = ctx.Process(target=_hog, args=(1 - cpu if cpu in (0, 1) else 0, stop), daemon=True)
    hog.start()
    stop_ui = threading.Event()
    threading.Thread(target=busy_python, args=(stop_ui,), daemon=True).start()
    saved = {name: (TRACE / name).read_text() for name in ("trace_clock", "tracing_cpumask", "buffer_size_kb",
                                                           "tracing_on")}
    clock_now = re.search(r"\[(\w+)\]", saved["trace_clock"])
    try:
        _write("trace_clock", "mono")  # time.perf_counter's clock
        _write("tracing_cpumask", format(1 << cpu, "x"))
        _write("buffer_size_kb", str(int(2000 * seconds)))
        _write("trace", "")
        for event in EVENTS:
            _write(f"events/{event}/enable", "1")
        _write("tracing_on", "1")
        child_in, to_child = ctx.Pipe(duplex=False)
        from_child, child_out = ctx.Pipe(duplex=False)
        load0, steal0 = os.getloadavg()[0], _steal_ms(cpu)
        proc = ctx.Process(target=_child, args=(child_in, child_out, os.getpid(), seconds, cpu,
                                                str(out_dir / "ticks.npz")))
        proc.start()
        timing: dict = {}
        while proc.is_alive() or from_child.poll():
            if from_child.poll(0.2):
                msg = from_child.recv()
                if msg[1] == "event" and msg[3] == "servo_timing":
                    timing = msg[4]
                elif msg[1] == "error":
                    raise SystemExit(f"Error: the traced trial failed: {msg[2]}")
                elif msg[1] == "outcome":
                    break
        proc.join()
        _write("tracing_on", "0")
        steal1, load1 = _steal_ms(cpu), os.getloadavg()[0]
        (out_dir / "trace.txt").write_text((TRACE / "trace").read_text())
    finally:
        _write("tracing_on", "0")
        for event in EVENTS:
            _write(f"events/{event}/enable", "0")
        _write("trace", "")
        _write("buffer_size_kb", saved["buffer_size_kb"].split()[0])
        _write("tracing_cpumask", saved["tracing_cpumask"].strip())
        if clock_now:
            _write("trace_clock", clock_now.group(1))
        _write("tracing_on", saved["tracing_on"].strip())
        stop_ui.set()
        stop.set()
        hog.join(timeout=5)
    return {"timing": timing, "steal_ms": steal1 - steal0, "load": [round(load0, 1), round(load1, 1)]}


def classify(trace_file: Path, ticks_file: Path, pid: int) -> tuple[list[dict], Counter, Counter]:
    """Each burst of late ticks with the cause of its first tick (see the module docstring)."""
    ticks = np.load(ticks_file)
    due, woke, starts = ticks["due"], ticks["woke"], ticks["starts"]
    events = []
    for line in trace_file.read_text().splitlines():
        m = LINE.match(line)
        if m:
            events.append((float(m.group(4)), m.group(5), m.group(6)))
    stamps = np.array([e[0] for e in events])
    late = set(np.nonzero(starts - due > 1e-3)[0].tolist())
    bursts, stalls, late_ticks = [], Counter(), Counter()
    for k in sorted(late):
        if k - 1 in late or k == 0:
            continue
        size = 1
        while k + size in late:
            size += 1
        a, b = starts[k - 1], starts[k]
        window = events[np.searchsorted(stamps, a):np.searchsorted(stamps, b)]
        gaps = np.diff([a, *(e[0] for e in window), b])
        silence = float(gaps.max())
        preempted = [e for e in window if e[1] == "sched_switch" and f"prev_pid={pid} " in e[2]
                     and "prev_state=R" in e[2]]
        woken = [e[0] for e in window if e[1] == "sched_wakeup" and f"pid={pid} " in e[2]]
        run = [e[0] for e in window if e[1] == "sched_switch" and f"next_pid={pid} " in e[2]]
        latency = run[-1] - woken[-1] if woken and run and run[-1] >= woken[-1] else 0.0
        excess = (b - a) - 1e-3
        if silence > 0.9e-3 and silence > 0.6 * excess:
            cause = "cpu silent"
        elif preempted:
            cause = "preempted by " + preempted[0][2].split("next_comm=")[1].split(" next_prio")[0]
        elif latency > 3e-4:
            cause = "wakeup latency"
        else:
            cause = "other"
        stalls[cause.split(" by ")[0]] += 1
        late_ticks[cause.split(" by ")[0]] += size
        bursts.append({"tick": int(k), "period_ms": round((b - a) * 1e3, 2), "late_ticks": size,
                       "silence_ms": round(silence * 1e3, 2), "woke_late_ms": round((woke[k] - due[k]) * 1e3 + 0.3, 2),
                       "wakeup_latency_ms": round(latency * 1e3, 2), "cause": cause})
    if 0 in late:  # the first tick has no previous start to measure from
        late_ticks["first tick"] += 1
    return bursts, stalls, late_ticks


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--cpu", type=int, default=max(os.sched_getaffinity(0)))
    parser.add_argument("--out", type=Path, default=Path("servo_stalls"))
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if os.geteuid() != 0 or not (TRACE / "trace").exists():
        print("Error: needs root and tracefs at /sys/kernel/tracing (mount -t tracefs none /sys/kernel/tracing)",
              file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    run = record(args.seconds, args.cpu, args.out)
    pid = int(run["timing"].get("rt", {}).get("pid", 0))
    bursts, stalls, late_ticks = classify(args.out / "trace.txt", args.out / "ticks.npz", pid)
    summary = {"load": run["load"], "steal_ms": run["steal_ms"], "ticks": run["timing"].get("ticks"),
               "late_1ms": run["timing"].get("late_1ms"),
               "period_jitter_us_p99": run["timing"].get("period_jitter_us_p99"),
               "stalls_by_cause": dict(stalls), "late_ticks_by_cause": dict(late_ticks), "bursts": bursts}
    if args.json:
        print(json.dumps(summary))
    else:
        for b in bursts:
            print(f"tick {b['tick']}: period {b['period_ms']} ms, {b['late_ticks']} late, silence {b['silence_ms']} "
                  f"ms, woke {b['woke_late_ms']} ms late, wake-up latency {b['wakeup_latency_ms']} ms: {b['cause']}")
        print(json.dumps({k: v for k, v in summary.items() if k != "bursts"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
