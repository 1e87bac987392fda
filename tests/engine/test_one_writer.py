"""One writer per session (issue 19): 20 real `studyctl run` / `studyctl resume` processes started at once on
one session → exactly one runs it, the 19 others exit non-zero with one line naming the lease holder, and the
stored data equal a single run's. On SQLite and PostgreSQL.

The 20 processes import studyctl first and then wait for a start file, so they reach the database within
a fraction of a second of each other (on a loaded 2-core machine, cold imports alone would spread them over
many seconds and most would only find a finished session).
"""

from __future__ import annotations

import hashlib
import itertools
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import yaml
from sqlalchemy import select

from studyctl.store import StudyStore
from studyctl.store.db import parse_url, sqlite_path
from studyctl.store.enrollment import enroll
from studyctl.store.integrity import verify_integrity
from studyctl.store.models import Event, SessionLease, Trial
from studyctl.store.workspace import init_workspace, open_study

pytestmark = pytest.mark.slow

PROTOCOL = Path(__file__).parent / "data" / "pty_protocol.yaml"
CODE = "PTY-AAAAA"
N = 20
SPEED = "0.3"  # the winner's session lasts ~30 s of wall time: every other process arrives while it runs
SCRIPT = {
    "likert": {"easy": [4, 5, 2], "prefer_feedback": [4]},
    "trials": {
        1: [{"t": 1.0, "request": "report", "answer": "3 4"}, {"t": 5.0, "request": "finish"}],
        2: [{"t": 2.5, "request": "finish"}],
    },
}
WAITER = textwrap.dedent('''
    import os, sys, time
    import studyctl.cli.app as app          # the whole CLI imported before the start signal
    import studyctl.engine.api  # noqa
    go = sys.argv[1]
    while not os.path.exists(go):
        time.sleep(0.005)
    sys.exit(app.main(sys.argv[2:]))
''')
REFUSAL = re.compile(r"^Error: session 1 is being run by pid (\d+) on (\S+) since \d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC"
                     r"(?: .*)?; if that process is gone, studyctl resume 1 --take-over$")


_names = itertools.count()


def _workspace(root: Path, backend: str, pg_server) -> Path:
    db = None
    if backend == "postgresql":
        db = pg_server.create_database(f"onewriter_{root.name}_{next(_names)}")
    init_workspace(root, protocol=str(PROTOCOL), db=db)
    with open_study(workspace=root) as o:
        enroll(o.store, code=CODE)
    (root / "answers.yaml").write_text(yaml.safe_dump(SCRIPT))
    return root


def _url(ws: Path) -> str:
    with open_study(workspace=ws) as o:
        return o.store.db.url.render_as_string(hide_password=False)


def _together(ws: Path, argv: list[str], tmp: Path) -> list[subprocess.CompletedProcess]:
    """Start N processes that wait for one start file, release them at once, collect their results."""
    go = tmp / f"go-{time.monotonic_ns()}"
    waiter = tmp / "waiter.py"
    waiter.write_text(WAITER)
    env = dict(os.environ)
    env.pop("STUDYCTL_DB", None)
    procs = [subprocess.Popen([sys.executable, str(waiter), str(go), *argv], cwd=ws, env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(N)]
    time.sleep(8)  # let every process finish importing (they then poll for the file)
    go.write_text("go")
    results = []
    for p in procs:
        out, err = p.communicate(timeout=600)
        results.append(subprocess.CompletedProcess(p.args, p.returncode, out, err))
    return results


def _check_exactly_one(results, winner_message: str) -> None:
    winners = [r for r in results if r.returncode == 0]
    losers = [r for r in results if r.returncode != 0]
    assert len(winners) == 1, [r.stderr for r in results]
    assert winner_message in winners[0].stdout
    for r in losers:
        lines = r.stderr.strip().splitlines()
        assert "Traceback" not in r.stderr
        assert len(lines) == 1 and REFUSAL.match(lines[0]), r.stderr
        assert REFUSAL.match(lines[0]).group(2) == socket.gethostname()


def _digest_samples(store: StudyStore, trial_id: int) -> str:
    frame = store.read_samples(trial_id)
    return hashlib.sha256(frame.to_numpy().tobytes() + ",".join(frame.columns).encode()).hexdigest()


def dump(ws: Path) -> dict:
    """What a session stored, without ids, wall times or anything a second process would add by itself."""
    with open_study(workspace=ws) as o:
        store = o.store
        sessions = store.list_sessions(store.list_participants(o.study.id)[0].id)
        trials = store.list_trials()
        out = {
            "sessions": [(s.status, s.seed, s.resume_count) for s in sessions],
            "trials": [(t.plan_position, t.condition, t.status, t.timed_out, t.placement, t.outcome, t.invalid_reason,
                        [(r.t, r.payload, r.correct) for r in store.location_reports(t.id)],
                        _digest_samples(store, t.id)) for t in trials],
            "answers": [tuple(r) for r in
                        store.responses_frame().drop(columns=["answered_at"]).itertuples(index=False)],
        }
        with store.reading() as s:
            out["events"] = [(seq, kind, t_mono, payload) for seq, kind, t_mono, payload in s.execute(
                select(Event.seq, Event.kind, Event.t_mono, Event.payload).order_by(Event.seq)).all()]
            out["leases"] = s.scalars(select(SessionLease.session_id)).all()
        report = verify_integrity(store.db)
        assert report.ok, report.problems
    return out


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def backend(request):
    if request.param == "postgresql":
        request.getfixturevalue("pg_server")
    return request.param


def test_twenty_concurrent_runs_one_writer(backend, tmp_path, request):
    pg = request.getfixturevalue("pg_server") if backend == "postgresql" else None
    ref = _workspace(tmp_path / "ref", backend, pg)
    subprocess.run([sys.executable, "-m", "studyctl", "run", "-p", CODE, "--input", "answers.yaml"], cwd=ref,
                   check=True, capture_output=True, timeout=300)
    ws = _workspace(tmp_path / "ws", backend, pg)
    results = _together(ws, ["run", "-p", CODE, "--input", "answers.yaml", "--speed", SPEED], tmp_path)
    _check_exactly_one(results, "Session 1 (PTY-AAAAA): completed")
    got, want = dump(ws), dump(ref)
    assert len(got["sessions"]) == 1  # a participant who takes part once has one session
    assert got == want


def _kill_during_trial(ws: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "studyctl", "run", "-p", CODE, "--input", "answers.yaml",
                             "--speed", "1"], cwd=ws, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    url = _url(ws)
    deadline = time.monotonic() + 180
    try:
        with StudyStore.open(url) as store:
            while time.monotonic() < deadline and proc.poll() is None:
                with store.reading() as s:
                    running = s.scalar(select(Trial.id).where(Trial.status == "running", Trial.plan_position == 2))
                if running is not None:
                    break
                time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    assert running is not None, "never saw trial 2 running"


def _copy(ws: Path, dst: Path, backend: str, pg) -> Path:
    """A copy of the workspace and its database (the killed session as it was) for the single-resume reference."""
    shutil.copytree(ws, dst)
    if backend == "sqlite":
        return dst
    url = parse_url(_url(ws))
    new = pg.create_database(f"{url.database}_copy", template=url.database)
    toml = dst / "studyctl.toml"
    toml.write_text(toml.read_text().replace(url.database, new.rsplit("/", 1)[1]))
    return dst


def test_twenty_concurrent_resumes_after_a_kill_one_writer(backend, tmp_path, request):
    pg = request.getfixturevalue("pg_server") if backend == "postgresql" else None
    ws = _workspace(tmp_path / "ws", backend, pg)
    _kill_during_trial(ws)
    if backend == "sqlite":
        assert sqlite_path(parse_url(_url(ws))).exists()
    ref = _copy(ws, tmp_path / "ref", backend, pg)
    # the killed run's lease is left behind: a plain resume names it and the fix, writes nothing
    plain = subprocess.run([sys.executable, "-m", "studyctl", "resume", "1", "--input", "answers.yaml"], cwd=ws,
                           capture_output=True, text=True, timeout=300)
    assert plain.returncode != 0 and plain.stderr.count("\n") == 1, plain.stderr
    assert re.fullmatch(r"Error: session 1 is still held by pid \d+ on \S+ since [\d:\- ]+ UTC, which is gone "
                        r"\(.*\); to continue the session, take it over \(audited\): studyctl resume 1 "
                        r"--take-over\n", plain.stderr), plain.stderr
    single = subprocess.run([sys.executable, "-m", "studyctl", "resume", "1", "--input", "answers.yaml",
                             "--take-over"], cwd=ref, capture_output=True, text=True, timeout=300)
    assert single.returncode == 0, single.stderr
    results = _together(ws, ["resume", "1", "--input", "answers.yaml", "--speed", SPEED, "--take-over"], tmp_path)
    _check_exactly_one(results, "Session 1 (PTY-AAAAA): completed")
    got, want = dump(ws), dump(ref)
    assert got == want
    with open_study(workspace=ws) as o:
        frame = o.store.audit_frame()
    take_overs = frame[frame.action == "session.take_over"]
    assert len(take_overs) == 1 and "--take-over: the owner process is gone" in take_overs.details.iloc[0]
