"""Write an analysis result to a folder: tidy CSV tables, PNG figures, a self-contained HTML report and
Markdown.

Layout of ``out_dir``::

    tests.csv            one row per test / pair / interval (columns ROW_COLUMNS)
    cells.csv            n, mean, SD, median … per metric × condition × group (× level)
    units.csv            the analysed value of every participant × condition (× level)
    proportions.csv      pooled proportions with Wilson intervals (proportion metrics)
    percent_change.csv, likert.csv, descriptives.csv   when the plan asks for them
    effect_sizes.csv     bootstrap intervals of the effect sizes (when the caller computed them)
    model_coefficients.csv   mixed-model and ordinal coefficients with Wald intervals (likewise)
    missing.csv          every value that is missing, and why
    figures/<id>.png     one per plan figure, 300 dpi (and <id>.svg, <id>.pdf: ``figure_formats``)
    report.html          everything above in one file (figures embedded as base64 PNG)
    report.md            the same as Markdown (figures linked from figures/)
    tables.tex           every table of the report as LaTeX (booktabs), captioned by its section
    summary.json         headline numbers, partial flag and problems (machine-readable)

Files are written to temporary names and renamed into place, so a failure never leaves a half-written
file; an unwritable folder is refused before anything is computed.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from studyctl.analysis.results import FigureData
from studyctl.errors import ConfigError

if TYPE_CHECKING:
    from studyctl.analysis.results import AnalysisResult


@dataclass(frozen=True)
class ReportFiles:
    """What :func:`write_report` wrote."""

    out_dir: Path
    html: Path
    markdown: Path
    tables: tuple[Path, ...]
    figures: tuple[Path, ...]
    partial: bool
    problems: tuple[str, ...]
    timings: Mapping[str, float]

    def to_frame(self) -> pd.DataFrame:
        rows = [{"kind": "html", "path": str(self.html)}, {"kind": "markdown", "path": str(self.markdown)}]
        rows += [{"kind": "table", "path": str(p)} for p in self.tables]
        rows += [{"kind": "figure", "path": str(p)} for p in self.figures]
        return pd.DataFrame(rows, columns=["kind", "path"])


def ensure_writable(out_dir: Path | str) -> Path:
    """Create ``out_dir`` if needed and prove it is writable; raise a one-line ConfigError otherwise."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-test-", dir=out)
        os.close(fd)
        os.unlink(probe)
    except FileExistsError:
        raise ConfigError(
            f"cannot write the report to {str(out)!r}: it exists and is not a folder; choose another --out"
        ) from None
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise ConfigError(
            f"cannot write the report to {str(out)!r}: {reason}; choose a writable folder with --out"
        ) from None
    return out


def check_figure_formats(figure_formats: Sequence[str]) -> list[str]:
    """The figure formats, checked (before anything is computed): png, svg, pdf."""
    from studyctl.report.figures import FORMATS

    formats = list(dict.fromkeys(f.strip().lower() for f in figure_formats if f.strip()))
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ConfigError(
            f"--figure-format {','.join(bad) or repr('')}: allowed are {', '.join(FORMATS)} (comma-separated, "
            "e.g. --figure-format png,svg,pdf)"
        )
    return formats


def _atomic_write(path: Path, data: bytes | str) -> Path:
    mode = "wb" if isinstance(data, bytes) else "w"
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, mode, **({} if isinstance(data, bytes) else {"encoding": "utf-8", "newline": ""})) as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _csv(frame: pd.DataFrame) -> str:
    return frame.to_csv(index=False, lineterminator="\n", float_format="%.10g")


def write_report(
    result: AnalysisResult,
    out_dir: Path | str,
    *,
    figure_data: Mapping[str, FigureData] | None = None,
    on_step: Callable[[str], None] | None = None,
    figure_formats: Sequence[str] = ("png", "svg", "pdf"),
) -> ReportFiles:
    """Write tables, figures, HTML and Markdown for ``result`` into ``out_dir``.

    Parameters
    ----------
    result
        From :func:`studyctl.analysis.analyze` / :func:`studyctl.analysis.execute.run_plan`.
    out_dir
        Created if missing; must be writable (checked first).
    figure_data
        Trace and model-curve data by figure id; ``result.figures`` when not given. A figure without its
        data is drawn as a notice and listed in ``problems``.
    on_step
        Called with the name of each step (progress display).
    figure_formats
        Files written per figure: ``png`` (300 dpi, always written), ``svg``, ``pdf``.
    """
    from studyctl.report import document
    from studyctl.report.compose import draw_figure

    formats = check_figure_formats(figure_formats)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    out = ensure_writable(out_dir)
    (out / "figures").mkdir(exist_ok=True)
    plan = result.plan
    problems = list(result.problems)
    tables: list[Path] = []

    def table(name: str, frame: pd.DataFrame | None) -> None:
        if frame is None:
            return
        tables.append(_atomic_write(out / f"{name}.csv", _csv(frame)))

    if on_step:
        on_step("tables")
    table("tests", result.to_frame())
    for name in ("cells", "units", "proportions", "percent_change", "likert", "descriptives", "agreement",
                 "effect_sizes", "model_coefficients"):
        frame = result.tables.get(name)
        if frame is not None and not frame.empty:
            table(name, frame)
    table("missing", result.missing)
    if "notes" in result.tables:
        table("notes", result.tables["notes"])
    timings["tables_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    figures: dict[str, bytes] = {}
    figure_paths: list[Path] = []
    from studyctl.report.figures import figure_bytes

    for fig_spec in plan.figures:
        if on_step:
            on_step(f"figure {fig_spec.id}")
        data = (result.figures if figure_data is None else figure_data).get(fig_spec.id)
        fig, problem = draw_figure(result, fig_spec, data)
        if problem:
            problems.append(f"figure {fig_spec.id}: {problem}")
        png = figure_bytes(fig, "png")  # always: the HTML embeds it, the Markdown links it
        figures[fig_spec.id] = png
        figure_paths.append(_atomic_write(out / "figures" / f"{fig_spec.id}.png", png))
        for fmt in formats:
            if fmt != "png":
                figure_paths.append(_atomic_write(out / "figures" / f"{fig_spec.id}.{fmt}", figure_bytes(fig, fmt)))
    timings["figures_s"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    if on_step:
        on_step("documents")
    html = _atomic_write(out / "report.html", document.html(result, figures, problems, base=out))
    pngs = [p.name for p in figure_paths if p.suffix == ".png"]
    md = _atomic_write(out / "report.md", document.markdown(result, pngs, problems, base=out))
    tex = _atomic_write(out / "tables.tex", document.latex_tables(result, problems, base=out))
    tables.append(tex)
    summary = document.summary(result, problems, base=out)
    _atomic_write(out / "summary.json", json.dumps(summary, indent=2, default=_json_default) + "\n")
    timings["documents_s"] = time.perf_counter() - t2
    timings["total_s"] = time.perf_counter() - t0
    return ReportFiles(
        out_dir=out,
        html=html,
        markdown=md,
        tables=tuple(tables),
        figures=tuple(figure_paths),
        partial=result.partial or bool(problems),
        problems=tuple(problems),
        timings=timings,
    )


def _json_default(value: Any) -> Any:
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        v = float(value)
        return None if math.isnan(v) else v
    if isinstance(value, Path):
        return str(value)
    return str(value)
