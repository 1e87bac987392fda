"""report.terminal.bench_tables: what ``studyctl bench NAME`` prints, from a benchmark result."""

from __future__ import annotations

from rich.console import Console

from studyctl.bench import BenchResult
from studyctl.report.terminal import bench_tables


def _text(tables) -> str:
    console = Console(record=True, width=100)
    for t in tables:
        console.print(t)
    return console.export_text()


def test_figures_beside_their_peers_then_the_results_own_tables():
    result = BenchResult(name="x", figures={"step_us": 1.234567, "late_pct": 2e-5},
                         peers={"step_us": 3.0, "numpy": 4.5},
                         tables={"rounds": [{"round": "a", "ms": 0.123456}, {"round": "b", "ms": 7}], "empty": []})
    tables = bench_tables(result)
    assert [t.title for t in tables] == ["studyctl bench x", "rounds"]  # an empty table is left out
    lines = [line.split("│")[1:-1] for line in _text(tables[:1]).splitlines() if line.startswith("│")]
    assert [[c.strip() for c in cells] for cells in lines] == [
        ["step_us", "1.235", "3"],  # four significant digits
        ["late_pct", "2e-05", ""],  # no peer
        ["numpy", "", "4.5"],  # a peer without a figure of its own
    ]
    assert "0.1235" in _text(tables[1:]) and "│ 7 " in _text(tables[1:])  # an int stays as it is
