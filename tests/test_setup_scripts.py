"""scripts/apt-install.sh (used by ensure-postgres.sh and ensure-browser.sh): a held apt lock is waited for, bounded.

A stand-in ``apt-get`` on PATH answers as apt 2.6 does while another process holds the lists lock (`update` fails
at once: it ignores DPkg::Lock::Timeout), so the waiting is tested without root or a real package manager."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "apt-install.sh"

FAKE_APT = """#!/usr/bin/env bash
echo "$*" >> "{log}"
if [[ " $* " == *" update "* ]]; then
    n=$(cat "{count}" 2>/dev/null || echo 0); echo $((n + 1)) > "{count}"
    if [ "$n" -lt "{locked}" ]; then
        echo "E: Could not get lock /var/lib/apt/lists/lock. It is held by process 4242 (apt-get)" >&2
        echo "E: Unable to lock directory /var/lib/apt/lists/" >&2
        exit 100
    fi
fi
exit 0
"""


def _run(tmp_path: Path, locked: int, wait_s: float) -> tuple[subprocess.CompletedProcess, list[str], float]:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    log, count = tmp_path / "calls.log", tmp_path / "count"
    fake = bin_dir / "apt-get"
    fake.write_text(FAKE_APT.format(log=log, count=count, locked=locked))
    fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "STUDYCTL_APT_WAIT_S": str(wait_s),
           "STUDYCTL_APT_RETRY_S": "0.2"}
    start = time.monotonic()
    run = subprocess.run(["bash", str(SCRIPT), "postgresql"], env=env, capture_output=True, text=True, timeout=60)
    return run, log.read_text().splitlines() if log.exists() else [], time.monotonic() - start


def test_a_locked_update_is_retried_until_the_lock_is_free(tmp_path):
    run, calls, _ = _run(tmp_path, locked=3, wait_s=30)
    assert run.returncode == 0, run.stderr
    updates = [c for c in calls if "update" in c.split()]
    assert len(updates) == 4 and all("DPkg::Lock::Timeout=30" in c for c in updates)
    assert calls[-1].split()[-1] == "postgresql" and "install" in calls[-1].split()
    assert "DPkg::Lock::Timeout=" in calls[-1]  # install waits by itself, for what is left of the wait
    assert run.stderr.count("locked by another apt or dpkg; waiting (up to 30 s)") == 1


def test_the_wait_is_bounded_and_says_why(tmp_path):
    run, calls, took = _run(tmp_path, locked=10_000, wait_s=1)
    assert run.returncode == 1 and took < 20
    assert "still locked after 1 s" in run.stderr and "STUDYCTL_APT_WAIT_S" in run.stderr
    assert not any("install" in c.split() for c in calls)  # nothing installed behind a lock it never got


def test_another_update_failure_is_not_waited_for(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "apt-get"
    fake.write_text("#!/usr/bin/env bash\necho 'E: The repository is not signed.' >&2\nexit 100\n")
    fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "STUDYCTL_APT_RETRY_S": "0.2"}
    run = subprocess.run(["bash", str(SCRIPT), "chromium"], env=env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 1 and "not signed" in run.stderr and "waiting" not in run.stderr
