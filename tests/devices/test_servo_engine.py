"""Hardware trials in the servo process, driven by the engine: the same records as the in-process loop, and a
session that survives the death of either process with its device in the safe state."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest
from polling import wait_for
from sqlalchemy import select

from studyctl.engine.api import resume_session, run_session
from studyctl.engine.trial_loop import TIMING_FAULTS
from studyctl.engine.ui import Script
from studyctl.store import StudyStore
from studyctl.store.models import Event, Trial

pytestmark = pytest.mark.slow

SCRIPT = {
    "default_likert": 3,
    "trials": {i: [{"t": 0.3, "request": "report", "answer": "2 5"}, {"t": 0.7, "request": "finish"}]
               for i in range(1, 5)},
}


def _kinds(rows):
    """Event kinds without the servo's own events and a loaded machine's pacing faults with what follows them (the
    recovery and the safety layer's second ramp-up)."""
    out, paced = [], False
    for k, p in rows:
        rule = (p or {}).get("rule")
        if k in ("servo_timing", "servo_clock") or (
                k in ("device_fault", "device_recovered") and rule in TIMING_FAULTS):
            paced = paced or k == "device_recovered"
            continue
        if k == "safety" and rule == "ramp_done" and paced:
            continue
        out.append(k)
    return out


def _records(store, sid):
    """Per trial (plan order): event kinds in order, the report payloads, the scene truth and the sample columns."""
    out = []
    with store.reading() as s:
        trials = list(s.scalars(select(Trial).where(Trial.session_id == sid).order_by(Trial.id)))
        for tr in trials:
            rows = s.execute(select(Event.kind, Event.payload).where(Event.trial_id == tr.id)
                             .order_by(Event.seq)).all()
            # the servo process's own events, and a loaded machine's pacing faults (the in-process loop beside the
            # store stalls on a busy machine: why the servo process exists; `bench servo` measures it)
            kinds = _kinds(rows)
            out.append({
                "status": tr.status,
                "kinds": kinds,
                "reports": [p for k, p in rows if k == "report"],
                "truth": [p for k, p in rows if k == "scene_truth"],
                "ticks": next(p["ticks"] for k, p in rows if k == "trial_loop_end"),
                "servo": sum(k == "servo_timing" for k, _ in rows),
                "rt": [p["rt"] for k, p in rows if k == "servo_timing"],
            })
    for rec, tr in zip(out, trials, strict=True):
        frame = store.read_samples(tr.id)
        rec["columns"] = list(frame.columns)
        rec["rows"] = len(frame)
    return out


def _alive(pid: int) -> bool:
    try:
        return open(f"/proc/{pid}/stat").read().split()[2] != "Z"
    except FileNotFoundError:
        return False


def test_servo_and_in_process_paths_record_the_same(study):
    a, code_a = study("bio_inspired_palpation", "novice")
    servo = run_session(a.store, code_a, virtual=False, script=Script.from_mapping(SCRIPT), rehearse=True, seed=11)
    inproc = run_session(a.store, code_a, virtual=False, script=Script.from_mapping(SCRIPT), rehearse=True, seed=11,
                         servo=False)
    rs, ri = _records(a.store, servo.session_id), _records(a.store, inproc.session_id)
    assert [r["servo"] for r in rs] == [1, 1, 1, 1] and [r["servo"] for r in ri] == [0, 0, 0, 0]
    for x, y in zip(rs, ri, strict=True):
        assert x["status"] == y["status"] == "completed"
        assert x["kinds"] == y["kinds"]
        assert x["reports"] == y["reports"] and x["truth"] == y["truth"]
        assert x["columns"] == y["columns"] and "force_n" in x["columns"] and "balloon_pct" in x["columns"]
        assert x["rows"] == x["ticks"] and y["rows"] == y["ticks"]
        assert abs(x["ticks"] - y["ticks"]) <= 2  # both 0.7 s at 50 Hz on a real clock
    # one servo process served the whole session (not one per trial), and it ended with the session
    pids = {r["rt"][0]["pid"] for r in rs}
    assert len(pids) == 1 and [r["rt"][0]["trial_in_process"] for r in rs] == [1, 2, 3, 4]
    assert pids != {os.getpid()} and not _alive(pids.pop())


RUNNER = textwrap.dedent('''
    import sys
    from studyctl.engine.api import run_session
    from studyctl.engine.ui import Script
    from studyctl.store import StudyStore
    url, code, script = sys.argv[1], sys.argv[2], sys.argv[3]
    with StudyStore.open(url) as store:
        run_session(store, code, virtual=False, script=script, rehearse=True, log=lambda m: print(m, flush=True))
''')


def _children(pid: int) -> list[int]:
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True).stdout
    return [int(x) for x in out.split()]


def _servo_pid(parent: int) -> int | None:
    for child in _children(parent):
        try:
            cmd = open(f"/proc/{child}/cmdline", "rb").read().replace(b"\0", b" ").decode()
        except FileNotFoundError:  # it ended between the listing and here
            continue
        if "multiprocessing" in cmd and "resource_tracker" not in cmd:
            return child
    return None


def _trial_running(url: str) -> bool:
    with StudyStore.open(url) as store, store.reading() as s:
        return s.scalar(select(Trial.id).where(Trial.status == "running")) is not None


@pytest.mark.parametrize("victim", ["parent", "child"])
def test_killing_either_process_leaves_a_resumable_session_and_a_safe_device(study, tmp_path, victim):
    opened, code = study("bio_inspired_palpation", "novice")
    url = f"sqlite:///{tmp_path / 'bio_inspired_palpation' / 'study.db'}"
    long = {**SCRIPT, "trials": {**SCRIPT["trials"], 1: [{"t": 30.0, "request": "finish"}]}}
    script = tmp_path / "script.json"
    script.write_text(json.dumps(long))
    runner = tmp_path / "runner.py"
    runner.write_text(RUNNER)
    proc = subprocess.Popen([sys.executable, str(runner), url, code, str(script)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        # trial 1 (30 s long) has started and its servo child exists; then its loop gets going (spawn + imports).
        # A runner that ended meanwhile (a device fault on a machine too loaded to keep the board's 0.1 s
        # sensor deadline) fails the test with what it said.
        end = time.monotonic() + 180
        while not (_trial_running(url) and _servo_pid(proc.pid)):
            if proc.poll() is not None or time.monotonic() > end:
                proc.kill()
                out, err = proc.communicate(timeout=30)
                raise AssertionError(f"trial 1 never ran in a servo process (runner exit {proc.returncode}): "
                                     f"{out[-2000:]} {err[-2000:]}")
            time.sleep(0.05)
        time.sleep(2.0)
        # looked up at kill time: the servo of the trial running now (a pid found earlier may be another's)
        servo = _servo_pid(proc.pid)
        if servo is None:
            out, err = proc.communicate(timeout=30)
            raise AssertionError(f"no servo process while trial 1 should run (runner exit {proc.returncode}): {err}")
        os.kill(proc.pid if victim == "parent" else servo, signal.SIGKILL)
        if victim == "parent":
            proc.wait(timeout=10)
            # the orphaned child notices, ends the trial and puts the device in its safe state, then exits
            wait_for(lambda: not os.path.exists(f"/proc/{servo}") or
                     open(f"/proc/{servo}/stat").read().split()[2] == "Z", timeout=10, what="the orphaned servo to end")
        else:
            out, err = proc.communicate(timeout=30)
            assert proc.returncode != 0
            assert "servo process failed" in err and "exit code -9" in err and "safe state commanded" in err, err
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    with StudyStore.open(url) as store:
        sess = store.list_sessions(store.get_participant(opened.study.id, code).id)[-1]
        assert sess.status in ("running", "interrupted")
        # a killed parent leaves its lease behind (taken over explicitly); a parent that saw its child die ended
        # cleanly and released it
        result = resume_session(store, sess.id, script=Script.from_mapping(SCRIPT), take_over=victim == "parent")
        assert result.status == "completed" and result.trials_completed == 4 and result.trials_aborted == 1


MAIN_SCRIPT = textwrap.dedent('''
    import sys
    MARKER = {marker!r}
    if __name__ == "__mp_main__":  # this script run again inside the servo process
        open(MARKER, "w").close()
    if __name__ == "__main__":
        from studyctl.engine.servo import ServoSpec, run_trial_in_servo_process
        from studyctl.plugins.interfaces import TrialInfo
        spec = ServoSpec(info=TrialInfo("c", 0.2, 50.0), device="sim_palpation", realtime=False)
        result = run_trial_in_servo_process(spec)
        print(result.ended_by, result.ticks, round(result.start_s, 3))
''')


def test_the_servo_process_does_not_run_the_coordinators_main_script_again(tmp_path):
    """``spawn`` re-runs a script ``__main__`` in the child; the ``studyctl`` console script would import the whole
    CLI into every trial's servo process. Started from a script, the servo process runs the trial without it."""
    marker = tmp_path / "main-ran-in-child"
    script = tmp_path / "coordinator.py"
    script.write_text(MAIN_SCRIPT.format(marker=str(marker)))
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr
    ended_by, ticks, start_s = out.stdout.split()
    assert ended_by == "time_limit" and int(ticks) >= 5 and float(start_s) > 0
    assert not marker.exists()
