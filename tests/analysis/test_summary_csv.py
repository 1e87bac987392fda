"""Plans over summary data: seed 003's published counts re-analysed, and bad CSV files."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from studyctl.analysis import analyze, load_plan, read_summary_csv
from studyctl.errors import AnalysisError

PLAN = "pseudo_haptic_palpation_published"


@pytest.fixture(scope="module")
def published():
    return analyze(load_plan(PLAN))


def test_wilson_intervals_match_the_paper(published):
    """Fig. 5b / Section 3: Se with 95% Wilson intervals, to the digits the paper prints.

    The paper rounds the limits outwards (lower down, upper up) to 0.1 %: 50/60 has the Wilson limits
    0.71968 and 0.90688, printed 71.9 and 90.7; 47/60 has 0.66380 and 0.86881, printed 66.3 and 86.9.
    """
    rows = {r.groups: r for r in published.rows_for("sensitivity_wilson")}
    expected = {"PHF_FF": (83.3, 71.9, 90.7), "PHF": (50.0, 37.7, 62.3), "FF": (78.3, 66.3, 86.9)}
    for level, (se, lo, hi) in expected.items():
        r = rows[level]
        assert r.status == "ok" and r.method == "Wilson score interval"
        outward = (round(100 * r.estimate, 1), math.floor(1000 * r.ci_low) / 10, math.ceil(1000 * r.ci_high) / 10)
        assert outward == (se, lo, hi), level
        assert abs(100 * r.ci_low - lo) < 0.1 and abs(100 * r.ci_high - hi) < 0.1
    assert rows["manual"].n_per_group == "50/60"


def test_table2_newcombe_margins_and_decisions(published):
    """Table 2, Se rows: margin (the paper's CI column), |Δp| and significance for every pair."""
    rows = {r.groups: r for r in published.rows_for("sensitivity_pairs")}
    expected = {
        "manual vs FF": (0.142, 0.050, False),
        "manual vs PHF": (0.167, 0.333, True),
        "FF vs PHF": (0.171, 0.283, True),
        "FF vs PHF_FF": (0.142, 0.050, False),
        "PHF vs PHF_FF": (0.167, 0.333, True),
    }
    for pair, (margin, dp, sig) in expected.items():
        r = rows[pair]
        assert round(r.statistic, 3) == margin, pair
        assert round(abs(r.estimate), 3) == dp, pair
        assert r.significant is sig, pair
    equal = rows["manual vs PHF_FF"]
    assert equal.estimate == 0 and equal.significant is False
    assert "NULL" in equal.warnings  # the paper prints NULL for the equal pair


def test_pooled_counts_refuse_per_participant_tests(tmp_path):
    plan = load_plan(PLAN)
    text = (
        Path(plan.source_path).read_text().replace("data/pseudo_haptic_palpation_published.csv", str(plan.csv_path()))
    )
    extra = "  - id: ranks\n    test: kruskal_wallis\n    metrics: [sensitivity]\n    compare: condition\nfigures:\n"
    p = tmp_path / "plan.yaml"
    p.write_text(text.replace("figures:\n", extra, 1))
    result = analyze(load_plan(p))
    (row,) = result.rows_for("ranks")
    assert row.status == "not_computed"
    assert "needs per-participant values; the data source has pooled counts" in row.warnings
    assert result.partial


def write_csv(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "data.csv"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("metric,condition,value\nx,a,1\nx,b,abc\n", r"data.csv:3: column 'value': expected a number, found 'abc'"),
        ("metric,condition,successes,n\nx,a,5,3\n", r"data.csv:2: successes \(5\) exceed n \(3\)"),
        ("metric,condition,successes,n\nx,a,1.5,3\n", r"data.csv:2: column 'successes': expected a whole number"),
        ("metric,condition,colour\n", r"data.csv:1: unknown column\(s\) 'colour'"),
        ("metric,value\n", r"data.csv:1: missing required column 'condition'"),
        ("# only a comment\n", r"data.csv: no header row"),
        ("metric,condition,successes\n", r"need both 'successes' and 'n'"),
        ("metric,condition,value\nx,a\n", r"data.csv:2: expected 3 cells, found 2"),
        ("metric,condition,value\nx,a,nan\n", r"expected a finite number"),
    ],
)
def test_bad_csv_is_named_by_line(tmp_path, text, message):
    with pytest.raises(AnalysisError, match=message):
        read_summary_csv(write_csv(tmp_path, text))


def test_empty_cells_are_listed_as_missing(tmp_path):
    table = read_summary_csv(
        write_csv(tmp_path, "# provenance\nmetric,condition,participant,value\nt,a,P1,3\nt,a,P2,\n")
    )
    assert len(table.frame) == 1
    (miss,) = table.missing.itertuples()
    assert miss.participant == "P2" and "empty value cell at line 4" in miss.reason
