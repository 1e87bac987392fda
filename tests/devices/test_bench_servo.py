"""studyctl bench servo: both paths measured in one run, with the hog started and stopped by the bench."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow


def test_bench_servo_json_has_both_paths_and_the_realtime_report():
    studyctl = str(Path(sys.executable).parent / "studyctl")
    out = subprocess.run([studyctl, "bench", "servo", "--quick", "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    for side in ("figures", "peers"):
        for key in ("period_jitter_us_p99_loaded", "late_ticks_pct_loaded", "loop_cpu_s"):
            assert math.isfinite(data[side][key]) and data[side][key] >= 0, (side, key)
    assert 0 < data["figures"]["servo_start_s"] < 120  # measured: spawn to the trial's time 0
    rows = data["tables"]["real-time pacing with the other core busy"]
    assert [r["loop"] for r in rows] == ["servo process", "in-process (peer)"]
    assert all(r["ticks"] > 1500 for r in rows)  # 2 s at 1 kHz each
    assert any("sched" in n and "gc" in n for n in data["notes"])
    if sys.platform.startswith("linux"):  # the hypervisor's share of the pinned loop's CPU, from /proc/stat
        assert math.isfinite(data["figures"]["loop_cpu_steal_ms"]) and data["figures"]["loop_cpu_steal_ms"] >= 0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/stat")
def test_cpu_steal_is_read_for_the_loops_cpu_only():
    import os

    from studyctl.engine.realtime import cpu_steal_ms

    cpu = max(os.sched_getaffinity(0))
    with open("/proc/stat") as f:
        field = next(line.split()[8] for line in f if line.startswith(f"cpu{cpu} "))
    assert cpu_steal_ms(cpu) >= int(field) * 1000.0 / os.sysconf("SC_CLK_TCK")  # never goes back
    assert cpu_steal_ms(None) is None and cpu_steal_ms(10_000) is None
