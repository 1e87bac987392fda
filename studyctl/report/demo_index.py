"""The demo's front page and terminal headline lines: formatting of what `workflows.demo` measured."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from studyctl.report.findings import agreement_headline
from studyctl.report.render import _env
from studyctl.report.style import fmt_p


def demo_index_html(runs: Sequence[Any], out: Path, seed: int, sim_rate_hz: float | None) -> str:
    """``index.html`` of a demo folder: one row per study (:class:`~studyctl.workflows.demo.StudyRun`)."""
    rows = []
    for r in runs:
        status = "FAILED: " + r.error.splitlines()[0] if r.error else ("partial results" if r.partial else "complete")
        rows.append({
            "study": r.study, "population": r.population, "participants": r.participants,
            "trials_completed": r.trials_completed, "tests": r.tests, "significant": r.significant,
            "agreement": r.agreement, "simulate_s": r.simulate_s, "total_s": r.total_s, "status": status,
            "error": bool(r.error), "link": Path(r.report).relative_to(out).as_posix() if r.report else "",
        })
    return _env().get_template("demo_index.html.j2").render(rows=rows, seed=seed, sim_rate_hz=sim_rate_hz)


def headline_tests(result: Any) -> list[str]:
    """A few lines for the terminal: each paper-role omnibus/two-sample test with its p-value."""
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


def agreement_line(result: Any) -> str:
    """The simulated-vs-published fractions of a report, or "" when the study has no targets."""
    return agreement_headline(result) or ""
