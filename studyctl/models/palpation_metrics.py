"""Nodule-detection metrics of the tissue-palpation studies (seeds 002 and 003), from logged reports.

A trial's reports (``{"x_mm", "y_mm", "t"}``, as the ``report`` events record them) are matched one-to-one
to the scene's nodules (``truth()["nodules"]``, same frame): a report is a *hit* when it lies within
``hit_radius_mm`` (a protocol parameter: ``trial.report.hit_radius``) of a nodule centre that no other report
claimed. Among all one-to-one matchings the one with most hits is used, ties broken by the smallest total
distance (``scipy.optimize.linear_sum_assignment``), so the result does not depend on the order of the
reports. Every report that is not a hit — outside all radii or a second report of a found nodule — is a
*false report*.

* sensitivity ``Se = nodules found / nodules`` (seed 003 §2.7),
* positive predictive value ``PPV = hits / reports`` (undefined, NaN, without reports),
* detection time: the time the participant took until they declared they had found all nodules, i.e. the
  trial's duration (seed 003's stopwatch time; seed 002's completion time).

Pooled over trials (:func:`pool_scores`) the counts are summed, as both papers do (60 nodules per method in
seed 003).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from studyctl.errors import AnalysisError, ModelParameterError

SCORE_COLUMNS = (
    "nodules",
    "reports",
    "nodules_found",
    "hits",
    "false_reports",
    "sensitivity",
    "ppv",
    "detection_time_s",
    "first_hit_s",
    "hit_radius_mm",
)
NODULE_COLUMNS = ("nodule", "x_mm", "y_mm", "found", "report_index", "distance_mm", "t_s")


@dataclass(frozen=True)
class NoduleMatch:
    """One nodule's outcome: found or not, by which report (index in report order), how far, when."""

    nodule: str
    x_mm: float
    y_mm: float
    found: bool
    report_index: int | None
    distance_mm: float
    t_s: float


@dataclass(frozen=True)
class PalpationScore:
    """Detection outcome of one trial. ``report_hits[i]`` says whether report ``i`` was a hit."""

    nodules: int
    reports: int
    nodules_found: int
    hits: int
    false_reports: int
    sensitivity: float
    ppv: float
    detection_time_s: float
    first_hit_s: float
    hit_radius_mm: float
    per_nodule: tuple[NoduleMatch, ...]
    report_hits: tuple[bool, ...]

    def to_frame(self) -> pd.DataFrame:
        """One row with columns :data:`SCORE_COLUMNS`."""
        return pd.DataFrame([[getattr(self, c) for c in SCORE_COLUMNS]], columns=list(SCORE_COLUMNS))

    def nodule_frame(self) -> pd.DataFrame:
        """One row per nodule with columns :data:`NODULE_COLUMNS`."""
        return pd.DataFrame(
            [[getattr(m, c) for c in NODULE_COLUMNS] for m in self.per_nodule], columns=list(NODULE_COLUMNS)
        )


def _point(row: Mapping[str, Any], what: str, k: int) -> tuple[float, float]:
    try:
        x, y = float(row["x_mm"]), float(row["y_mm"])
    except (KeyError, TypeError, ValueError):
        raise AnalysisError(f"{what}[{k}] = {dict(row)!r} needs numeric x_mm and y_mm") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise AnalysisError(f"{what}[{k}] has a non-finite position ({x}, {y})")
    return x, y


def match_reports(
    reports: Sequence[Mapping[str, Any]], nodules: Sequence[Mapping[str, Any]], hit_radius_mm: float
) -> tuple[list[int | None], list[float]]:
    """Optimal one-to-one matching: for each nodule the index of its report (or None) and the distance.

    Maximises the number of report–nodule pairs within ``hit_radius_mm``, then minimises their total
    distance.
    """
    from scipy.optimize import linear_sum_assignment

    if not (isinstance(hit_radius_mm, int | float) and math.isfinite(hit_radius_mm) and hit_radius_mm > 0):
        raise ModelParameterError(
            f"hit_radius_mm = {hit_radius_mm!r}; must be a positive distance in mm (protocol trial.report.hit_radius)"
        )
    rp = np.array([_point(r, "reports", k) for k, r in enumerate(reports)], dtype=float).reshape(-1, 2)
    nd = np.array([_point(n, "nodules", k) for k, n in enumerate(nodules)], dtype=float).reshape(-1, 2)
    owner: list[int | None] = [None] * len(nd)
    dist = [math.nan] * len(nd)
    if len(rp) == 0 or len(nd) == 0:
        return owner, dist
    d = np.hypot(nd[:, None, 0] - rp[None, :, 0], nd[:, None, 1] - rp[None, :, 1])
    inside = d <= hit_radius_mm
    # A pair inside the radius costs −big plus its distance scaled into [0, 1): with big above the number of
    # possible pairs, one more hit always outweighs any change of distances, so hits are maximised first
    # and total distance second.
    big = 2.0 * (min(d.shape) + 1)
    cost = np.where(inside, -big + d / (1.0 + float(d.max())), 0.0)
    rows, cols = linear_sum_assignment(cost)
    for i, j in zip(rows, cols, strict=True):
        if inside[i, j]:
            owner[int(i)] = int(j)
            dist[int(i)] = float(d[i, j])
    return owner, dist


def score_trial(
    reports: Sequence[Mapping[str, Any]],
    nodules: Sequence[Mapping[str, Any]],
    hit_radius_mm: float,
    duration_s: float,
) -> PalpationScore:
    """Score one trial.

    Parameters
    ----------
    reports : the participant's reports in the order made, each with ``x_mm``, ``y_mm`` (and ``t`` in s)
    nodules : the scene truth's nodules, each with ``x_mm``, ``y_mm`` (and ``name``)
    hit_radius_mm : the protocol's hit radius
    duration_s : the trial's duration (detection time)

    Raises
    ------
    AnalysisError
        No nodules, malformed positions, a negative or non-finite duration.
    ModelParameterError
        A hit radius that is not a positive number.
    """
    if not nodules:
        raise AnalysisError("the scene truth lists no nodules; sensitivity is undefined")
    if not (isinstance(duration_s, int | float) and math.isfinite(duration_s) and duration_s >= 0):
        raise AnalysisError(f"trial duration {duration_s!r} s must be a finite number ≥ 0")
    owner, dist = match_reports(reports, nodules, hit_radius_mm)
    hit_flags = [False] * len(reports)
    per = []
    for k, (nod, j, dd) in enumerate(zip(nodules, owner, dist, strict=True)):
        x, y = _point(nod, "nodules", k)
        t = math.nan
        if j is not None:
            hit_flags[j] = True
            t = float(reports[j].get("t", math.nan))
        per.append(NoduleMatch(str(nod.get("name", k + 1)), x, y, j is not None, j, dd, t))
    found = sum(m.found for m in per)
    hits = sum(hit_flags)
    times = [m.t_s for m in per if m.found and math.isfinite(m.t_s)]
    return PalpationScore(
        nodules=len(nodules),
        reports=len(reports),
        nodules_found=found,
        hits=hits,
        false_reports=len(reports) - hits,
        sensitivity=found / len(nodules),
        ppv=hits / len(reports) if reports else math.nan,
        detection_time_s=float(duration_s),
        first_hit_s=min(times) if times else math.nan,
        hit_radius_mm=float(hit_radius_mm),
        per_nodule=tuple(per),
        report_hits=tuple(hit_flags),
    )


@dataclass(frozen=True)
class PooledScore:
    """Counts summed over trials (one method of seed 003: 20 participants × 3 nodules = 60 nodules)."""

    trials: int
    nodules: int
    nodules_found: int
    reports: int
    hits: int
    sensitivity: float
    ppv: float
    mean_detection_time_s: float

    def to_frame(self) -> pd.DataFrame:
        cols = ("trials", "nodules", "nodules_found", "reports", "hits", "sensitivity", "ppv", "mean_detection_time_s")
        return pd.DataFrame([[getattr(self, c) for c in cols]], columns=list(cols))


def pool_scores(scores: Iterable[PalpationScore]) -> PooledScore:
    """Sum nodules, found nodules, reports and hits over trials; Se and PPV of the sums."""
    rows = list(scores)
    if not rows:
        raise AnalysisError("no trials to pool")
    n = sum(s.nodules for s in rows)
    f = sum(s.nodules_found for s in rows)
    r = sum(s.reports for s in rows)
    h = sum(s.hits for s in rows)
    return PooledScore(
        trials=len(rows),
        nodules=n,
        nodules_found=f,
        reports=r,
        hits=h,
        sensitivity=f / n,
        ppv=h / r if r else math.nan,
        mean_detection_time_s=float(np.mean([s.detection_time_s for s in rows])),
    )


def chance_hit_probability(
    nodules: Sequence[Mapping[str, Any]], hit_radius_mm: float, area_mm: tuple[float, float, float, float]
) -> float:
    """Probability that one report placed uniformly at random on ``area_mm`` (x0, x1, y0, y1) lands within
    the hit radius of some nodule (discs clipped to the area, overlaps counted once; by a 1 mm grid).

    The yardstick of "better than chance" for a virtual participant's PPV.
    """
    x0, x1, y0, y1 = (float(v) for v in area_mm)
    if not (x1 > x0 and y1 > y0):
        raise AnalysisError(f"area {area_mm!r} must be (x0, x1, y0, y1) with x1 > x0 and y1 > y0")
    xs = np.arange(x0 + 0.5, x1, 1.0)
    ys = np.arange(y0 + 0.5, y1, 1.0)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    covered = np.zeros(gx.shape, dtype=bool)
    for k, nod in enumerate(nodules):
        x, y = _point(nod, "nodules", k)
        covered |= np.hypot(gx - x, gy - y) <= hit_radius_mm
    return float(covered.mean())
