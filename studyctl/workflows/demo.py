"""``studyctl demo``: simulate the four reference studies, analyse them and write their reports.

From nothing: for each reference protocol a fresh workspace is created, paper-sized cohorts of seeded
virtual participants run their sessions through the real engine (controllers, simulated devices,
scenes), the shipped analysis plan is run on the resulting database, and the report is written to
``<out>/<study>/``. ``<out>/index.html`` links the four reports.

Participants' sessions run as tasks of a pool of worker processes (one per core by default), the costliest
studies first, so every core stays busy until the last session ends; a study is analysed by the pool as soon as
its last session ends.
A study that fails does not stop the others, and a failed session makes its study's report partial; both
are reported with their reasons.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import time
import traceback
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from studyctl.analysis.plan import load_plan
from studyctl.engine.loop_rates import SIM_RATE_HZ, check_sim_rate
from studyctl.errors import ConfigError, StudyctlError, UsageError
from studyctl.report.build import ensure_writable
from studyctl.report.demo_index import agreement_line, demo_index_html, headline_tests
from studyctl.workflows.report import build_report
from studyctl.workflows.simulate import Cohort, create_cohort, run_participant

#: (protocol / plan name, participants in the paper)
REFERENCE_STUDIES: tuple[tuple[str, int], ...] = (
    ("bio_inspired_palpation", 25),
    ("needle_insertion", 12),
    ("data_driven_palpation", 20),
    ("pseudo_haptic_palpation", 20),
)
DEFAULT_SEED = 2024
MARKER = ".studyctl-demo"  # written into folders the demo created, so a re-run may replace them

Event = tuple[str, str, int, int, str]  # (study, stage, done, total, message)


@dataclass(frozen=True)
class StudyRun:
    """One reference study in the demo: stage timings, where its report is, what went wrong."""

    study: str
    participants: int
    simulate_s: float = 0.0
    metrics_s: float = 0.0
    analyze_s: float = 0.0
    figures_s: float = 0.0
    report_s: float = 0.0
    total_s: float = 0.0
    trials_completed: int = 0
    trials_not_completed: int = 0
    tests: int = 0
    significant: int = 0
    partial: bool = False
    report: str = ""
    problems: tuple[str, ...] = ()
    error: str = ""
    headline: tuple[str, ...] = ()
    population: str = ""  # which population the virtual people came from (describe_choice line)
    agreement: str = ""  # the report's simulated-vs-published fractions ("" without targets)

    COLUMNS = (
        "study",
        "participants",
        "simulate_s",
        "metrics_s",
        "analyze_s",
        "figures_s",
        "report_s",
        "total_s",
        "trials_completed",
        "trials_not_completed",
        "tests",
        "significant",
        "partial",
        "report",
        "error",
        "population",
        "agreement",
    )

    @property
    def ok(self) -> bool:
        return not self.error


@dataclass(frozen=True)
class DemoResult:
    """All studies of one demo run."""

    out_dir: Path
    index: Path
    studies: tuple[StudyRun, ...]
    total_s: float
    workers: int
    seed: int
    notes: tuple[str, ...] = field(default_factory=tuple)
    sim_rate_hz: float | None = None

    @property
    def ok(self) -> bool:
        return all(s.ok for s in self.studies)

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame(
            [{c: getattr(s, c) for c in StudyRun.COLUMNS} for s in self.studies], columns=list(StudyRun.COLUMNS)
        )


def _prepare_folder(folder: Path) -> None:
    """Make ``folder`` an empty demo folder: refuse to clear anything the demo did not create."""
    if folder.exists():
        if not folder.is_dir():
            raise ConfigError(f"{folder} is a file; choose another --out folder for the demo")
        if any(folder.iterdir()):
            if not (folder / MARKER).exists():
                raise ConfigError(
                    f"{folder} is not empty and was not made by studyctl demo; choose another --out "
                    "folder (the demo only replaces its own output)"
                )
            shutil.rmtree(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / MARKER).write_text("created by studyctl demo; a later demo run may replace this folder\n")


def _prepare_study(name: str, participants: int, seed: int, out: Path, sim_rate_hz: float | None) -> Cohort:
    """Fresh folder, workspace and enrolled cohort of one study (main process, fast)."""
    folder = out / name
    _prepare_folder(folder)
    return create_cohort(name, participants, seed, folder / "workspace", sim_rate_hz=sim_rate_hz)


def _session_task(cohort: Cohort, code: str) -> tuple[str, float]:
    """One participant's session (runs in a worker process)."""
    t0 = time.perf_counter()
    status = run_participant(cohort, code)
    return status, time.perf_counter() - t0


def _report_task(cohort: Cohort, folder: str) -> dict[str, Any]:
    """Analysis and report of one study (runs in a worker process)."""
    rep = build_report(load_plan(cohort.study), folder, workspace=cohort.workspace)
    result, files = rep.result, rep.files
    frame = result.to_frame()
    sig = frame[(frame["status"] == "ok") & (frame["significant"] == True)]  # noqa: E712
    return {
        "metrics_s": result.timings.get("metrics_s", 0.0),
        "analyze_s": rep.timings["analyze_s"],
        "figures_s": files.timings.get("figures_s", 0.0) + rep.timings.get("figure_data_s", 0.0),
        "report_s": rep.timings["report_s"],
        "trials_completed": int(result.data.info.get("trials_completed", 0)),
        "trials_not_completed": int(sum((result.data.info.get("trials_other") or {}).values())),
        "tests": len(frame),
        "significant": len(sig),
        "partial": files.partial,
        "report": str(files.html),
        "problems": tuple(files.problems),
        "headline": tuple(headline_tests(result)),
        "agreement": agreement_line(result),
    }


def _run_pool(
    n_workers: int,
    by_cost: Sequence[tuple[str, int]],
    *,
    enrol: Callable[[str, int], bool],
    cohorts: dict[str, Cohort],
    out: Path,
    sessions_done: dict[str, int],
    session_done: Callable[[str, str, str | None, float, str | None], None],
    report_done: Callable[[str, dict[str, Any] | None, str | None], None],
    reportable: Callable[[str], bool],
    emit: Callable[[Event], None],
) -> None:
    """Sessions and reports on a pool of ``n_workers`` processes, every core busy from the first second to the last.

    Two things the pool's own first-in-first-out queue would waste, measured on the demo (2 workers, session 43):
    the workers waited ~4 s for all four studies to be enrolled before the first session was handed out, and a
    study's report, submitted when its last session ended, queued behind every other study's sessions, so the four
    reports (~28 CPU s) ran after the last session on two cores with one of them often idle. Here each study's
    sessions are handed out as soon as it is enrolled (the workers start while the main process enrols the next),
    at most ``n_workers + 1`` tasks are in the pool at a time (one waiting, so a worker never idles between tasks),
    and a report goes ahead of every session still waiting.
    """
    waiting: deque[tuple[str, str | None]] = deque()  # (study, participant code); code None = the study's report
    in_pool: dict[Future[Any], tuple[str, str | None]] = {}
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=n_workers, mp_context=ctx) as pool:

        def top_up() -> None:
            while waiting and len(in_pool) <= n_workers:
                name, code = waiting.popleft()
                try:
                    if code is None:
                        future = pool.submit(_report_task, cohorts[name], str(out / name))
                    else:
                        future = pool.submit(_session_task, cohorts[name], code)
                except Exception as exc:  # noqa: BLE001 - a broken pool: say so for this task's study
                    finished(name, code, None, exc)
                    continue
                in_pool[future] = (name, code)

        def finished(name: str, code: str | None, value: Any, exc: BaseException | None) -> None:
            if code is None:
                report_done(name, value, None if exc is None else _error_text(exc))
                return
            if exc is None:
                session_done(name, code, value[0], value[1], None)
            else:
                session_done(name, code, None, 0.0, _error_text(exc))
            all_ended(name)

        def all_ended(name: str) -> None:
            if sessions_done[name] == len(cohorts[name].codes):
                # As soon as a study's last session ends: its analysis goes ahead of the sessions still waiting.
                if reportable(name):
                    emit((name, "analyse", 0, 1, "metrics, tests, figures"))
                    waiting.appendleft((name, None))
                else:
                    report_done(name, None, None)

        for name, n in by_cost:
            if enrol(name, n):
                waiting.extend((name, code) for code in cohorts[name].codes)
                if not cohorts[name].codes:
                    all_ended(name)
                top_up()
        while in_pool:
            ready, _ = wait(in_pool, return_when=FIRST_COMPLETED)
            for future in ready:
                name, code = in_pool.pop(future)
                exc = future.exception()
                finished(name, code, None if exc is not None else future.result(), exc)
            top_up()


def _error_text(exc: BaseException) -> str:
    if isinstance(exc, StudyctlError):
        return str(exc)
    if isinstance(exc, BrokenProcessPool):
        # the worker's own error, if it had one, went to its stderr: say where to look and the usual causes
        return (f"a worker process ended abruptly ({' '.join(str(exc).split())}): it was killed or ran out of memory, "
                "or a script runs the demo without an `if __name__ == \"__main__\":` guard; the worker's own error, "
                "if any, is on stderr above")
    # A bug in a plugin or here: keep the traceback in the result (demo.json), not on screen. The screen shows the
    # first line, so the message is put on one: multiprocessing's own errors (e.g. a script that runs the demo without
    # an ``if __name__ == "__main__":`` guard) start with a line break and would show as a bare "RuntimeError:".
    return f"{type(exc).__name__}: {' '.join(str(exc).split())}\n" + "".join(traceback.format_exception(exc, limit=6))


def run_demo(
    out_dir: str | Path = "reports",
    *,
    seed: int = DEFAULT_SEED,
    studies: Sequence[tuple[str, int]] = REFERENCE_STUDIES,
    workers: int | None = None,
    sim_rate_hz: float | None = SIM_RATE_HZ,
    on_event: Callable[[Event], None] | None = None,
) -> DemoResult:
    """Run the whole demo; see the module docstring.

    In this process, every study gets a fresh workspace and its enrolled cohort, costliest study first; a pool of
    worker processes runs the participants' sessions, each study's as soon as it is enrolled and the longest
    studies first, so that both cores stay busy until the last session ends (participants of one study write to
    its SQLite database concurrently, one short transaction at a time); the pool analyses each study and writes
    its report as soon as the study's last session has ended, ahead of the sessions still waiting.

    Parameters
    ----------
    out_dir
        Where the reports go (one folder per study plus ``index.html``); must be writable.
    seed
        Master seed of every study (the same seed gives the same data and reports).
    studies
        (protocol, participants) pairs; default the four reference studies at paper size.
    workers
        Parallel worker processes; default the number of CPU cores.
    sim_rate_hz
        Loop-rate cap of the simulated sessions for controllers that allow it (see
        :func:`studyctl.engine.api.run_session`); None runs every condition at its protocol's rate.
    on_event
        Receives progress events ``(study, stage, done, total, message)`` in the calling process.
    """
    if getattr(mp.current_process(), "_inheriting", False):
        # A spawned worker is importing the script that runs the demo (multiprocessing's own flag for that phase, the
        # one its "bootstrapping phase" error reads). Going on would clear and refill the demo folder the parent is
        # writing: refuse before anything is touched.
        raise UsageError(
            "run_demo was called while one of its worker processes was starting: a worker imports the script that "
            'runs the demo, so put the call under `if __name__ == "__main__":` (Python\'s multiprocessing requires '
            "it; the studyctl command already does)"
        )
    t0 = time.perf_counter()
    if sim_rate_hz is not None:

        check_sim_rate(sim_rate_hz)
    out = ensure_writable(out_dir)
    emit = on_event or (lambda _event: None)
    n_workers = max(1, workers or os.cpu_count() or 1)
    runs: dict[str, dict[str, Any]] = {name: {"study": name, "participants": n} for name, n in studies}
    started = {name: time.perf_counter() for name, _ in studies}
    cohorts: dict[str, Cohort] = {}
    done: dict[str, int] = {}
    sim_s: dict[str, float] = {}
    completed: dict[str, int] = {}

    def enrol(name: str, n: int) -> bool:
        emit((name, "simulate", 0, n, "enrolling"))
        try:
            cohorts[name] = _prepare_study(name, n, seed, out, sim_rate_hz)
        except Exception as exc:  # noqa: BLE001 - recorded per study; the others go on
            runs[name]["error"] = _error_text(exc)
            emit((name, "failed", 1, 1, runs[name]["error"].splitlines()[0]))
            return False
        done[name], sim_s[name], completed[name] = 0, 0.0, 0
        return True

    def session_done(name: str, code: str, status: str | None, seconds: float, error: str | None) -> None:
        done[name] += 1
        sim_s[name] += seconds
        if status == "completed":
            completed[name] += 1
        if error:  # the study is still analysed from the sessions that ran; the gap is reported
            runs[name].setdefault("session_errors", []).append(f"session of {code} failed: {error.splitlines()[0]}")
        emit((name, "simulate", done[name], len(cohorts[name].codes), code))

    def report_done(name: str, info: dict[str, Any] | None, error: str | None) -> None:
        if info is not None:
            runs[name].update(info)
        lost = runs[name].get("session_errors", [])
        if lost:
            runs[name]["problems"] = tuple(lost) + tuple(runs[name].get("problems", ()))
            runs[name]["partial"] = True
        if error:
            runs[name]["error"] = error
        runs[name]["total_s"] = time.perf_counter() - started[name]
        emit(
            (
                name,
                "failed" if runs[name].get("error") else "done",
                1,
                1,
                (runs[name].get("error") or "report written").splitlines()[0],
            )
        )

    reportable = lambda name: "error" not in runs[name]  # noqa: E731
    # Longest first: sessions of the costliest studies start at once, short ones fill the gaps.
    by_cost = sorted(studies, key=lambda s: -_COST.get(s[0], 1.0))
    if n_workers == 1:
        for name, n in by_cost:
            enrol(name, n)
        for name, code in [(study, code) for study, _ in by_cost if study in cohorts for code in cohorts[study].codes]:
            try:
                status, seconds = _session_task(cohorts[name], code)
                session_done(name, code, status, seconds, None)
            except Exception as exc:  # noqa: BLE001
                session_done(name, code, None, 0.0, _error_text(exc))
        for name in cohorts:
            if reportable(name):
                emit((name, "analyse", 0, 1, "metrics, tests, figures"))
                try:
                    report_done(name, _report_task(cohorts[name], str(out / name)), None)
                except Exception as exc:  # noqa: BLE001
                    report_done(name, None, _error_text(exc))
            else:
                report_done(name, None, None)
    else:
        _run_pool(n_workers, by_cost, enrol=enrol, cohorts=cohorts, out=out, sessions_done=done,
                  session_done=session_done, report_done=report_done, reportable=reportable, emit=emit)
    ordered = []
    for name, _n in studies:
        info = runs[name]
        info.setdefault("total_s", time.perf_counter() - started[name])
        if name in cohorts:
            from studyctl.populations import describe_choice

            info["population"] = describe_choice(cohorts[name].population, name, False)
        ordered.append(
            StudyRun(
                simulate_s=sim_s.get(name, 0.0), **{k: v for k, v in info.items() if k in StudyRun.__dataclass_fields__}
            )
        )
    index = _write_index(out, ordered, seed, sim_rate_hz)
    return DemoResult(
        out_dir=out,
        index=index,
        studies=tuple(ordered),
        total_s=time.perf_counter() - t0,
        workers=n_workers,
        seed=seed,
        sim_rate_hz=sim_rate_hz,
    )


# Rough relative cost per participant (simulated trial time × loop rate; measured order of the stages).
_COST = {
    "pseudo_haptic_palpation": 4 * 100 * 1000 * 2,
    "needle_insertion": 15 * 40 * 1000,
    "data_driven_palpation": 2 * 60 * 1000,
    "bio_inspired_palpation": 4 * 90 * 50 * 20,
}


def _write_index(out: Path, runs: Sequence[StudyRun], seed: int, sim_rate_hz: float | None) -> Path:
    path = out / "index.html"
    path.write_text(demo_index_html(runs, out, seed, sim_rate_hz), encoding="utf-8")
    (out / "demo.json").write_text(json.dumps([asdict(r) for r in runs], indent=2, default=str) + "\n")
    return path
