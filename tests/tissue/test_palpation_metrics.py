"""Nodule-detection metrics and the manual-condition outcome helper."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.errors import AnalysisError, ModelParameterError, UsageError
from studyctl.models.manual_palpation import parse_positions, validate_manual_outcome
from studyctl.models.palpation_metrics import (
    NODULE_COLUMNS,
    SCORE_COLUMNS,
    chance_hit_probability,
    match_reports,
    pool_scores,
    score_trial,
)

NODULES = [
    {"name": "A", "x_mm": 30.0, "y_mm": 85.0},
    {"name": "B", "x_mm": 85.0, "y_mm": 80.0},
    {"name": "C", "x_mm": 60.0, "y_mm": 35.0},
]


def test_hits_false_reports_sensitivity_ppv():
    reports = [
        {"x_mm": 31.0, "y_mm": 88.0, "t": 40.0},  # A, 3.2 mm
        {"x_mm": 29.0, "y_mm": 84.0, "t": 45.0},  # A again: a false report
        {"x_mm": 10.0, "y_mm": 10.0, "t": 50.0},  # nowhere
        {"x_mm": 60.0, "y_mm": 44.9, "t": 60.0},  # C at 9.9 mm
    ]
    s = score_trial(reports, NODULES, hit_radius_mm=10.0, duration_s=73.6)
    assert (s.nodules, s.reports, s.nodules_found, s.hits, s.false_reports) == (3, 4, 2, 2, 2)
    assert s.sensitivity == pytest.approx(2 / 3) and s.ppv == pytest.approx(0.5)
    assert s.detection_time_s == 73.6 and s.first_hit_s == 45.0  # the closer A report is the one matched
    assert [m.found for m in s.per_nodule] == [True, False, True]
    assert s.report_hits == (False, True, False, True)
    assert list(s.to_frame().columns) == list(SCORE_COLUMNS)
    assert list(s.nodule_frame().columns) == list(NODULE_COLUMNS) and len(s.nodule_frame()) == 3


def test_radius_boundary_and_no_reports():
    s = score_trial([{"x_mm": 40.0, "y_mm": 85.0}], NODULES, 10.0, 10.0)
    assert s.hits == 1  # exactly on the radius counts
    s = score_trial([{"x_mm": 40.01, "y_mm": 85.0}], NODULES, 10.0, 10.0)
    assert s.hits == 0
    s = score_trial([], NODULES, 10.0, 12.0)
    assert s.sensitivity == 0.0 and math.isnan(s.ppv) and math.isnan(s.first_hit_s)


def test_matching_is_optimal_not_greedy():
    # one report sits between two nodules, a second report only reaches one of them; in report order a
    # greedy match gives the first report the nearer nodule and leaves the second without one
    nodules = [{"x_mm": 0.0, "y_mm": 0.0}, {"x_mm": 12.0, "y_mm": 0.0}]
    reports = [{"x_mm": 5.0, "y_mm": 0.0}, {"x_mm": -6.0, "y_mm": 0.0}]
    owner, dist = match_reports(reports, nodules, 8.0)
    assert owner == [1, 0] and dist == pytest.approx([6.0, 7.0])
    s = score_trial(reports, nodules, 8.0, 1.0)
    assert s.hits == 2 and s.sensitivity == 1.0
    # the order of the reports does not matter
    assert score_trial(reports[::-1], nodules, 8.0, 1.0).hits == 2


def test_pooling_sums_counts_like_the_papers():
    # seed 003, PHF+FF: 50 of 60 nodules over 20 participants
    rng = np.random.default_rng(0)
    found = np.array([3] * 10 + [2] * 10)
    scores = []
    for f in found:
        reps = [{"x_mm": n["x_mm"] + 1, "y_mm": n["y_mm"]} for n in NODULES[:f]] + [{"x_mm": 5.0, "y_mm": 5.0}]
        scores.append(score_trial(reps, NODULES, 10.0, float(rng.uniform(50, 100))))
    pooled = pool_scores(scores)
    assert (pooled.nodules, pooled.nodules_found) == (60, 50)
    assert pooled.sensitivity == pytest.approx(50 / 60)
    assert pooled.ppv == pytest.approx(50 / 70)
    assert list(pooled.to_frame().columns)[0] == "trials"


def test_chance_probability_is_the_covered_area():
    p = chance_hit_probability([{"x_mm": 60.0, "y_mm": 60.0}], 10.0, (0.0, 120.0, 0.0, 120.0))
    assert p == pytest.approx(math.pi * 100 / 14400, rel=0.01)
    overlapping = [{"x_mm": 60.0, "y_mm": 60.0}, {"x_mm": 60.0, "y_mm": 60.0}]
    assert chance_hit_probability(overlapping, 10.0, (0.0, 120.0, 0.0, 120.0)) == pytest.approx(p)


def test_bad_metric_input():
    with pytest.raises(ModelParameterError, match="hit_radius_mm"):
        score_trial([], NODULES, 0.0, 1.0)
    with pytest.raises(AnalysisError, match="no nodules"):
        score_trial([], [], 10.0, 1.0)
    with pytest.raises(AnalysisError, match=r"reports\[0\]"):
        score_trial([{"x_mm": "left"}], NODULES, 10.0, 1.0)
    with pytest.raises(AnalysisError, match="duration"):
        score_trial([], NODULES, 10.0, -1.0)


def test_manual_outcome_parsing_and_validation():
    assert parse_positions("35 80; 85.5, 75\n(10 12)") == [(35.0, 80.0), (85.5, 75.0), (10.0, 12.0)]
    assert parse_positions("  ") == []
    out = validate_manual_outcome("35 80; 85 75", "106", bounds_mm=(0, 120, 0, 120), time_limit_s=300)
    assert out.duration_s == 106.0
    assert out.reports == ({"x_mm": 35.0, "y_mm": 80.0, "t": 106.0}, {"x_mm": 85.0, "y_mm": 75.0, "t": 106.0})
    assert list(out.to_frame().columns) == ["report", "x_mm", "y_mm", "t_s", "duration_s"]
    # the records score like a haptic trial's
    assert score_trial(list(out.reports), NODULES, 10.0, out.duration_s).hits == 2


@pytest.mark.parametrize(
    "positions,duration,match",
    [
        ("35", 10, r"position 1 '35': give x and y in mm"),
        ("35 80; a b", 10, "position 2 'a b': x and y must be numbers"),
        ("130 80", 10, r"position 1 \(130, 80\) mm is off the phantom \(x 0–120, y 0–120 mm\)"),
        ("35 80", "soon", "give the stopwatch time in seconds"),
        ("35 80", -2, "must be a finite number of seconds"),
        ("35 80", 400, "longer than the trial limit of 300 s"),
        ("1 1; 2 2; 3 3", 10, "at most 2"),
        ([(1.0, float("nan"))], 10, "finite"),
    ],
)
def test_manual_outcome_errors(positions, duration, match):
    with pytest.raises(UsageError, match=match):
        validate_manual_outcome(positions, duration, bounds_mm=(0, 120, 0, 120), time_limit_s=300, max_reports=2)
