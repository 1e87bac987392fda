"""Outcome of a manual palpation trial (seeds 002 and 003), as the coordinator enters it.

In the manual conditions nobody touches the haptic device: the participant palpates the real phantom and
indicates where they felt nodules; the coordinator measures the positions on the phantom (mm, in the same
frame and orientation as the scene's truth for that trial) and reads the stopwatch (seed 003: ±1 s). The
session engine's prompts collect the text; :func:`parse_positions` and :func:`validate_manual_outcome` turn it
into the same report records a haptic trial produces, so the metrics treat both alike.

Errors are :class:`~studyctl.errors.UsageError` with one line that says what was wrong and what is allowed,
meant to be shown before re-asking.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import pandas as pd

from studyctl.errors import UsageError
from studyctl.inputs import xy_pair


@dataclass(frozen=True)
class ManualPalpationOutcome:
    """A validated manual trial: duration (s) and the found positions as report records.

    ``reports`` are ``{"x_mm", "y_mm", "t"}`` dicts (``t`` is the duration: the positions are indicated at
    the end), the shape ``run_trial`` records for haptic trials.
    """

    duration_s: float
    reports: tuple[dict[str, float], ...]
    note: str = ""

    def to_frame(self) -> pd.DataFrame:
        """One row per reported position: columns report, x_mm, y_mm, t_s, duration_s."""
        return pd.DataFrame(
            [(k + 1, r["x_mm"], r["y_mm"], r["t"], self.duration_s) for k, r in enumerate(self.reports)],
            columns=["report", "x_mm", "y_mm", "t_s", "duration_s"],
        )


def parse_positions(text: str) -> list[tuple[float, float]]:
    """Positions typed as ``x y`` pairs separated by ``;`` or new lines (``"35 80; 85.5, 75"``).

    An empty text means "none found". Raises :class:`UsageError` naming the bad entry.
    """
    out = []
    entries = [e.strip() for e in re.split(r"[;\n]+", text or "") if e.strip()]
    for k, entry in enumerate(entries, start=1):
        tokens = [t for t in re.split(r"[\s,]+", entry.strip("()[] ")) if t]
        where = f"position {k} {entry!r}"
        out.append(xy_pair(tokens, wrong_count=f"{where}: give x and y in mm, e.g. '35 80'; separate positions "
                           "with ';'", not_numbers=f"{where}: x and y must be numbers in mm"))
    return out


def validate_manual_outcome(
    positions: Iterable[Sequence[float]] | str,
    duration_s: float | str,
    *,
    bounds_mm: tuple[float, float, float, float] | None = None,
    time_limit_s: float | None = None,
    max_reports: int | None = None,
    note: str = "",
) -> ManualPalpationOutcome:
    """Validate what the coordinator entered for a manual palpation trial.

    Parameters
    ----------
    positions : found positions as (x, y) pairs in mm, or the typed text (see :func:`parse_positions`)
    duration_s : the stopwatch time in seconds (a number or its text)
    bounds_mm : (x_min, x_max, y_min, y_max) of the phantom's surface; positions outside are refused
    time_limit_s : the trial's limit, if any; a longer time is refused
    max_reports : the protocol's ``trial.report.max_reports``, if any
    note : free text stored with the outcome

    Raises
    ------
    UsageError
        Unparseable or non-finite values, a negative duration or one above the limit, positions off the
        phantom, more positions than allowed.
    """
    try:
        duration = float(duration_s)
    except (TypeError, ValueError):
        raise UsageError(f"time {duration_s!r}: give the stopwatch time in seconds, e.g. '95'") from None
    if not math.isfinite(duration) or duration < 0:
        raise UsageError(f"time {duration_s!r}: must be a finite number of seconds ≥ 0")
    if time_limit_s is not None and math.isfinite(time_limit_s) and duration > time_limit_s:
        raise UsageError(f"time {duration:g} s is longer than the trial limit of {time_limit_s:g} s")
    pairs = parse_positions(positions) if isinstance(positions, str) else [tuple(p) for p in positions]
    if max_reports is not None and len(pairs) > max_reports:
        raise UsageError(f"{len(pairs)} positions entered; the protocol allows at most {max_reports}")
    reports: list[dict[str, Any]] = []
    for k, pair in enumerate(pairs, start=1):
        if len(pair) != 2:
            raise UsageError(f"position {k} {pair!r}: give x and y in mm")
        try:
            x, y = float(pair[0]), float(pair[1])
        except (TypeError, ValueError):
            raise UsageError(f"position {k} {pair!r}: x and y must be numbers in mm") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise UsageError(f"position {k} ({x}, {y}): x and y must be finite numbers in mm")
        if bounds_mm is not None:
            x0, x1, y0, y1 = bounds_mm
            if not (x0 <= x <= x1 and y0 <= y <= y1):
                raise UsageError(
                    f"position {k} ({x:g}, {y:g}) mm is off the phantom (x {x0:g}–{x1:g}, y {y0:g}–{y1:g} mm)"
                )
        reports.append({"x_mm": x, "y_mm": y, "t": duration})
    return ManualPalpationOutcome(duration, tuple(reports), str(note))
