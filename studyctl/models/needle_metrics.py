"""The seed 001 performance metrics, computed from what a trial logged (samples and events).

The paper (Section 2.4) measures per trial: (a) the number of CT scans, (b) the duration to finish with a
90 s limit, (c) trajectory tracking — the shortest distance of the needle tip from the desired trajectory
(the segment from the desired incision point to the tumour centroid, its Figure 5), averaged over the
insertion — and (d) targeting accuracy, the final Euclidean distance of the tip from the tumour centroid.

Inputs are the stored samples (a DataFrame with ``t`` and the tip position ``x_mm``, ``y_mm``, ``z_mm``),
the trial's events (mappings with ``kind`` and ``t``) and the scene's ground truth (``incision_mm`` and
``tumour_center_mm``, as :meth:`studyctl.scenes.needle_liver.NeedleLiverScene.truth` returns it).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pandas as pd

from studyctl.errors import AnalysisError

TIP_COLUMNS = ("x_mm", "y_mm", "z_mm")


def _point(truth: Mapping[str, Any], key: str) -> np.ndarray:
    if key not in truth:
        raise AnalysisError(f"needle metrics: the scene truth lacks {key!r}; it has {', '.join(sorted(truth))}")
    p = np.asarray(truth[key], dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise AnalysisError(f"needle metrics: truth {key} = {truth[key]!r} must be three finite numbers (mm)")
    return p


def _tips(samples: pd.DataFrame) -> np.ndarray:
    missing = [c for c in ("t", *TIP_COLUMNS) if c not in samples.columns]
    if missing:
        raise AnalysisError(
            f"needle metrics: samples lack column(s) {', '.join(missing)}; they need t, x_mm, y_mm, z_mm"
        )
    return samples.loc[:, list(TIP_COLUMNS)].to_numpy(dtype=float)


def count_scans(events: Iterable[Mapping[str, Any]]) -> int:
    """Number of CT scans requested in the trial (``scan`` events; none in real-time conditions)."""
    return sum(1 for ev in events if ev.get("kind") == "scan")


def trial_duration(
    samples: pd.DataFrame, events: Iterable[Mapping[str, Any]], time_limit_s: float = 90.0
) -> float:
    """Seconds from the start to the end of the trial, capped at ``time_limit_s``.

    The end is the ``trial_loop_end`` event when it was logged, else the last sample's time.
    """
    if not time_limit_s > 0:
        raise AnalysisError(f"needle metrics: time_limit_s = {time_limit_s!r} must be > 0")
    end = None
    for ev in events:
        if ev.get("kind") == "trial_loop_end":
            end = float(ev["t"])
    if end is None:
        if len(samples) == 0:
            raise AnalysisError("needle metrics: no samples and no trial_loop_end event; the duration is unknown")
        end = float(samples["t"].iloc[-1])
    return min(max(end, 0.0), float(time_limit_s))


def tracking_errors(samples: pd.DataFrame, truth: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample tip distance (mm) from the planned segment, and which samples belong to the insertion.

    A sample belongs to the insertion while the tip is inside the liver (the sphere ``liver_center_mm``,
    ``liver_radius_mm`` of the truth). Without the liver sphere in ``truth``, samples whose tip has passed
    the plane through the incision point normal to the path, and lie within the planned segment's
    length of it, count instead.
    """
    a = _point(truth, "incision_mm")
    b = _point(truth, "tumour_center_mm")
    p = _tips(samples)
    d = b - a
    length = float(np.linalg.norm(d))
    if length <= 0:
        raise AnalysisError("needle metrics: the incision point and the tumour centroid coincide")
    u = d / length
    lam = (p - a) @ u
    closest = a + np.clip(lam, 0.0, length)[:, None] * u
    dist = np.linalg.norm(p - closest, axis=1)
    if "liver_center_mm" in truth and "liver_radius_mm" in truth:
        c = _point(truth, "liver_center_mm")
        r = float(truth["liver_radius_mm"])
        return dist, np.linalg.norm(p - c, axis=1) < r
    return dist, (lam >= 0.0) & (np.linalg.norm(p - a, axis=1) <= 1.5 * length)


def mean_tracking_error(samples: pd.DataFrame, truth: Mapping[str, Any]) -> float:
    """Mean tip distance (mm) from the planned segment over the insertion; NaN if the tip never got there."""
    dist, inserted = tracking_errors(samples, truth)
    if not inserted.any():
        return math.nan
    return float(dist[inserted].mean())


def targeting_error(samples: pd.DataFrame, truth: Mapping[str, Any]) -> float:
    """Final Euclidean distance (mm) of the needle tip from the tumour centroid (last sample)."""
    p = _tips(samples)
    if len(p) == 0:
        raise AnalysisError("needle metrics: no samples; the final tip position is unknown")
    return float(np.linalg.norm(p[-1] - _point(truth, "tumour_center_mm")))


@dataclass(frozen=True)
class NeedleTrialMetrics:
    """The four metrics of one trial (paper Section 2.4) plus how many samples the insertion spanned."""

    scans: int
    duration_s: float
    tracking_error_mm: float
    targeting_error_mm: float
    insertion_samples: int

    COLUMNS = ("scans", "duration_s", "tracking_error_mm", "targeting_error_mm", "insertion_samples")

    def to_frame(self) -> pd.DataFrame:
        """One row with the fixed columns :attr:`COLUMNS`."""
        return pd.DataFrame([asdict(self)], columns=list(self.COLUMNS))


def needle_trial_metrics(
    samples: pd.DataFrame,
    events: Sequence[Mapping[str, Any]],
    truth: Mapping[str, Any],
    *,
    time_limit_s: float = 90.0,
) -> NeedleTrialMetrics:
    """All four seed 001 metrics of one trial from its logged samples and events.

    Parameters
    ----------
    samples : DataFrame
        Columns ``t``, ``x_mm``, ``y_mm``, ``z_mm`` (needle tip, device frame), in time order.
    events : sequence of mappings
        The trial's events with ``kind`` and ``t`` (``scan``, ``trial_loop_end`` are used).
    truth : mapping
        ``incision_mm`` and ``tumour_center_mm`` of the trial's scene.
    time_limit_s : float
        The trial's time limit; the duration is capped at it (90 s in the paper).
    """
    dist, inserted = tracking_errors(samples, truth)
    return NeedleTrialMetrics(
        scans=count_scans(events),
        duration_s=trial_duration(samples, events, time_limit_s),
        tracking_error_mm=float(dist[inserted].mean()) if inserted.any() else math.nan,
        targeting_error_mm=targeting_error(samples, truth),
        insertion_samples=int(inserted.sum()),
    )
