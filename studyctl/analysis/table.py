"""The tidy metric table every analysis runs on, and reading it from a summary CSV.

One row per participant × trial × metric × level. ``value`` holds the number (for a proportion metric:
the successes) and ``denominator`` the chances (NaN for continuous and ordinal metrics). Rows without a
participant carry pooled counts (e.g. a published "50 of 60 nodules" table).

Nothing is dropped silently: whatever could not be computed is listed in ``missing`` with the reason.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from studyctl.errors import AnalysisError

COLUMNS = (
    "participant",
    "group",
    "condition",
    "trial",
    "repetition",
    "metric",
    "level",
    "value",
    "denominator",
)
MISSING_COLUMNS = ("participant", "group", "condition", "trial", "metric", "reason")


def empty_frame() -> pd.DataFrame:
    return pd.DataFrame({c: pd.Series(dtype="float64" if c in ("value", "denominator") else "object") for c in COLUMNS})


@dataclass(frozen=True)
class MetricTable:
    """Metric values of one study (or summary file) plus what is missing and why."""

    frame: pd.DataFrame
    missing: pd.DataFrame = field(default_factory=lambda: pd.DataFrame(columns=list(MISSING_COLUMNS)))
    source: str = ""
    study: str = ""
    #: extra information about the source (counts of participants, trials by status …)
    info: dict[str, object] = field(default_factory=dict)

    def to_frame(self) -> pd.DataFrame:
        """The values, columns :data:`COLUMNS`."""
        return self.frame.loc[:, list(COLUMNS)].copy()

    @property
    def pooled(self) -> bool:
        """True when the values carry no participant (summary counts)."""
        return bool(len(self.frame)) and self.frame["participant"].isna().all()

    def metrics(self) -> list[str]:
        return sorted(self.frame["metric"].dropna().unique())


def _number(text: str, where: str, column: str, *, whole: bool = False) -> float:
    try:
        value = float(text)
    except ValueError:
        raise AnalysisError(f"{where}: column {column!r}: expected a number, found {text!r}") from None
    if math.isnan(value) or math.isinf(value):
        raise AnalysisError(
            f"{where}: column {column!r}: expected a finite number, found {text!r}; "
            "leave the cell empty for a missing value"
        )
    if whole and (value < 0 or value != int(value)):
        raise AnalysisError(f"{where}: column {column!r}: expected a whole number ≥ 0, found {text!r}")
    return value


def read_summary_csv(path: Path | str, *, study: str = "") -> MetricTable:
    """Read per-participant values or pooled counts from a CSV file.

    Columns (header names, any order): ``metric`` and ``condition`` (required); ``participant``,
    ``group``, ``level``, ``repetition`` (optional); and either ``value`` (a number) or ``successes`` and
    ``n`` (whole numbers, successes ≤ n). Lines starting with ``#`` are comments (provenance headers).
    An empty ``value`` cell is a missing value and is listed in ``missing``.

    Raises
    ------
    AnalysisError
        Naming the file, line and column of the first bad cell.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise AnalysisError(f"{path}: no such file; check the plan's data.path") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise AnalysisError(f"{path}: cannot read the file ({exc})") from None
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip() and not line.startswith("#")]
    if not lines:
        raise AnalysisError(f"{path}: no header row; expected columns metric, condition and value (or successes, n)")
    header_line, header = lines[0]
    reader = csv.reader([header])
    columns = [c.strip() for c in next(reader)]
    allowed = {"metric", "condition", "participant", "group", "level", "repetition", "value", "successes", "n"}
    unknown = [c for c in columns if c not in allowed]
    if unknown:
        raise AnalysisError(
            f"{path}:{header_line}: unknown column(s) {', '.join(map(repr, unknown))}; "
            f"allowed: {', '.join(sorted(allowed))}"
        )
    for need in ("metric", "condition"):
        if need not in columns:
            raise AnalysisError(f"{path}:{header_line}: missing required column {need!r}")
    counts = "successes" in columns or "n" in columns
    if counts and not ("successes" in columns and "n" in columns):
        raise AnalysisError(f"{path}:{header_line}: pooled counts need both 'successes' and 'n' columns")
    if counts and "value" in columns:
        raise AnalysisError(f"{path}:{header_line}: give either 'value' or 'successes' and 'n', not both")
    if not counts and "value" not in columns:
        raise AnalysisError(f"{path}:{header_line}: missing column 'value' (or 'successes' and 'n')")

    rows: list[dict[str, object]] = []
    missing: list[dict[str, object]] = []
    for line_no, line in lines[1:]:
        cells = next(csv.reader([line]))
        where = f"{path}:{line_no}"
        if len(cells) != len(columns):
            raise AnalysisError(f"{where}: expected {len(columns)} cells, found {len(cells)}")
        rec = {c: v.strip() for c, v in zip(columns, cells, strict=True)}
        for need in ("metric", "condition"):
            if not rec[need]:
                raise AnalysisError(f"{where}: column {need!r} is empty")
        row: dict[str, object] = {
            "participant": rec.get("participant") or None,
            "group": rec.get("group") or None,
            "condition": rec["condition"],
            "trial": None,
            "repetition": rec.get("repetition") or None,
            "metric": rec["metric"],
            "level": rec.get("level") or None,
        }
        if counts:
            s = _number(rec["successes"], where, "successes", whole=True)
            n = _number(rec["n"], where, "n", whole=True)
            if s > n:
                raise AnalysisError(f"{where}: successes ({s:g}) exceed n ({n:g})")
            row["value"], row["denominator"] = s, n
        else:
            if rec["value"] == "":
                missing.append(
                    {
                        "participant": row["participant"],
                        "group": row["group"],
                        "condition": row["condition"],
                        "trial": None,
                        "metric": row["metric"],
                        "reason": f"empty value cell at line {line_no}",
                    }
                )
                continue
            row["value"], row["denominator"] = _number(rec["value"], where, "value"), np.nan
        rows.append(row)
    frame = pd.DataFrame(rows, columns=list(COLUMNS)) if rows else empty_frame()
    frame["value"] = frame["value"].astype(float)
    frame["denominator"] = frame["denominator"].astype(float)
    return MetricTable(
        frame=frame,
        missing=pd.DataFrame(missing, columns=list(MISSING_COLUMNS)),
        source=str(path),
        study=study,
        info={"rows": len(frame), "kind": "pooled counts" if counts else "values"},
    )
