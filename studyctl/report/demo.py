"""``studyctl demo``: simulate the four reference studies, analyse them and write their reports.

From nothing: for each reference protocol a fresh workspace is created, paper-sized cohorts of seeded
virtual participants run their sessions through the real engine (controllers, simulated devices,
scenes), the shipped analysis plan is run on the resulting database, and the report is written to
``<out>/<study>/``. ``<out>/index.html`` links the four reports.

Studies run in parallel worker processes (one per core by default; each study has its own database), the
longest first. A study that fails does not stop the others; the failure is reported with its reason.
"""

from __future__ import annotations

import html
import json
import multiprocessing as mp
import os
import shutil
import time
import traceback
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from studyctl.errors import ConfigError, StudyctlError

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


def run_study(name: str, participants: int, seed: int, out_dir: str, queue: Any = None) -> StudyRun:
    """Simulate, analyse and report one reference study (runs inside a worker process)."""

    def emit(stage: str, done: int, total: int, message: str = "") -> None:
        if queue is not None:
            queue.put((name, stage, done, total, message))

    t0 = time.perf_counter()
    folder = Path(out_dir) / name
    run = StudyRun(study=name, participants=participants)
    try:
        _prepare_folder(folder)
        from studyctl.analysis.simulate import simulate_study
        from studyctl.report.pipeline import build_report

        emit("simulate", 0, participants, "starting")
        sim = simulate_study(
            name, participants, seed, folder / "workspace", on_progress=lambda i, n, code: emit("simulate", i, n, code)
        )
        emit("analyse", 0, 1, "metrics and tests")
        rep = build_report(
            name, folder, workspace=folder / "workspace", on_step=lambda step: emit("analyse", 0, 1, step)
        )
        result, files = rep.result, rep.files
        frame = result.to_frame()
        sig = frame[(frame["status"] == "ok") & (frame["significant"] == True)]  # noqa: E712
        headline = tuple(_headline(result))
        run = StudyRun(
            study=name,
            participants=participants,
            simulate_s=sim.seconds,
            metrics_s=result.timings.get("metrics_s", 0),
            analyze_s=rep.timings["analyze_s"],
            figures_s=files.timings.get("figures_s", 0.0) + rep.timings.get("figure_data_s", 0.0),
            report_s=rep.timings["report_s"],
            total_s=time.perf_counter() - t0,
            trials_completed=sim.trials_completed,
            trials_not_completed=sim.trials_not_completed,
            tests=len(frame),
            significant=len(sig),
            partial=files.partial,
            report=str(files.html),
            problems=files.problems,
            headline=headline,
        )
        emit("done", 1, 1, "report written")
    except StudyctlError as exc:
        run = StudyRun(study=name, participants=participants, total_s=time.perf_counter() - t0, error=str(exc))
        emit("failed", 1, 1, str(exc))
    except Exception as exc:  # a bug in a plugin or here: keep the traceback in the result, not on screen
        tb = traceback.format_exc(limit=6)
        run = StudyRun(
            study=name,
            participants=participants,
            total_s=time.perf_counter() - t0,
            error=f"{type(exc).__name__}: {exc}\n{tb}",
        )
        emit("failed", 1, 1, f"{type(exc).__name__}: {exc}")
    return run


def _headline(result: Any) -> list[str]:
    """A few lines for the terminal: each paper-role omnibus/two-sample test with its p-value."""
    from studyctl.report.style import fmt_p

    out = []
    frame = result.to_frame()
    paper = frame[
        (frame["role"] == "paper") & frame["kind"].isin(["omnibus", "two_sample"]) & (frame["status"] == "ok")
    ]
    for r in paper.itertuples():
        if len(out) >= 4:
            break
        out.append(
            f"{r.test} {r.metric}{f' [{r.split}]' if r.split else ''}: {r.statistic_name} = "
            f"{r.statistic:.3g}, p = {fmt_p(r.p)}"
        )
    return out


def run_demo(
    out_dir: str | Path = "reports",
    *,
    seed: int = DEFAULT_SEED,
    studies: Sequence[tuple[str, int]] = REFERENCE_STUDIES,
    workers: int | None = None,
    on_event: Callable[[Event], None] | None = None,
) -> DemoResult:
    """Run the whole demo; see the module docstring.

    Parameters
    ----------
    out_dir
        Where the reports go (one folder per study plus ``index.html``); must be writable.
    seed
        Master seed of every study (the same seed gives the same data and reports).
    studies
        (protocol, participants) pairs; default the four reference studies at paper size.
    workers
        Parallel worker processes; default the number of CPU cores (at most the number of studies).
    on_event
        Receives progress events ``(study, stage, done, total, message)`` in the calling process.
    """
    from studyctl.report.build import ensure_writable

    t0 = time.perf_counter()
    out = ensure_writable(out_dir)
    n_workers = max(1, min(workers or os.cpu_count() or 1, len(studies)))
    runs: dict[str, StudyRun] = {}
    # Longest first: the study with the most simulated participant-time starts at once.
    order = sorted(studies, key=lambda s: -_expected_cost(*s))
    if n_workers == 1:
        for name, n in order:
            runs[name] = run_study(name, n, seed, str(out), _CallbackQueue(on_event))
    else:
        ctx = mp.get_context("spawn")
        with ctx.Manager() as manager:
            queue = manager.Queue()
            with ProcessPoolExecutor(max_workers=n_workers, mp_context=ctx) as pool:
                futures = {pool.submit(run_study, name, n, seed, str(out), queue): name for name, n in order}
                pending = set(futures)
                while pending:
                    _drain(queue, on_event)
                    done = {f for f in pending if f.done()}
                    for f in done:
                        runs[futures[f]] = f.result()
                    pending -= done
                    if pending:
                        time.sleep(0.1)
                _drain(queue, on_event)
    ordered = tuple(runs[name] for name, _ in studies)
    index = _write_index(out, ordered, seed)
    return DemoResult(
        out_dir=out, index=index, studies=ordered, total_s=time.perf_counter() - t0, workers=n_workers, seed=seed
    )


# Rough relative cost per participant (simulated trial time × loop rate), to start the longest study first.
_COST = {
    "needle_insertion": 15 * 40 * 1000,
    "pseudo_haptic_palpation": 4 * 100 * 1000,
    "data_driven_palpation": 2 * 40 * 1000,
    "bio_inspired_palpation": 4 * 90 * 50 * 20,
}


def _expected_cost(name: str, participants: int) -> float:
    return _COST.get(name, 1.0) * participants


class _CallbackQueue:
    """Queue stand-in for the single-process path: delivers events straight to the callback."""

    def __init__(self, callback: Callable[[Event], None] | None) -> None:
        self.callback = callback

    def put(self, event: Event) -> None:
        if self.callback is not None:
            self.callback(event)


def _drain(queue: Any, on_event: Callable[[Event], None] | None) -> None:
    while True:
        try:
            event = queue.get_nowait()
        except Exception:  # queue.Empty from the manager proxy
            return
        if on_event is not None:
            on_event(event)


def _write_index(out: Path, runs: Sequence[StudyRun], seed: int) -> Path:
    e = html.escape
    rows = []
    for r in runs:
        link = Path(r.report).relative_to(out).as_posix() if r.report else ""
        status = "FAILED: " + r.error.splitlines()[0] if r.error else ("partial results" if r.partial else "complete")
        rows.append(
            f"<tr><td>{e(r.study)}</td><td>{r.participants}</td><td>{r.trials_completed}</td>"
            f"<td>{r.tests}</td><td>{r.significant}</td><td>{r.total_s:.1f} s</td><td>{e(status)}</td>"
            f"<td>{f'<a href={chr(39)}{e(link)}{chr(39)}>report</a>' if link else ''}</td></tr>"
        )
    text = (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>studyctl demo</title>"
        "<style>body{font-family:system-ui,sans-serif;margin:2em auto;max-width:960px}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:4px 8px}</style></head><body>"
        "<h1>studyctl demo: the four reference studies</h1>"
        f"<p>Seeded virtual participants (seed {seed}) ran each protocol through the session engine; every number "
        "in the reports was computed from the study databases in the <code>workspace/</code> folders.</p>"
        "<table><tr><th>study</th><th>participants</th><th>completed trials</th><th>tests</th>"
        "<th>significant</th><th>time</th><th>status</th><th></th></tr>" + "".join(rows) + "</table></body></html>\n"
    )
    path = out / "index.html"
    path.write_text(text, encoding="utf-8")
    (out / "demo.json").write_text(json.dumps([asdict(r) for r in runs], indent=2, default=str) + "\n")
    return path
