"""Seed 000's "within 1 grid cell" (diagonals included), the one definition the metric, the palpator and the scripts
share, and the metric's matching built on it."""

from __future__ import annotations

from studyctl.analysis.metrics import match_cells
from studyctl.models.grid_cells import cell_distance, within_one_cell


def test_a_cell_and_its_eight_neighbours_are_within_one_cell_and_nothing_further():
    around = {(c, r) for c in range(1, 8) for r in range(1, 8) if within_one_cell((4, 4), (c, r))}
    assert around == {(c, r) for c in (3, 4, 5) for r in (3, 4, 5)}
    assert cell_distance((1, 1), (3, 2)) == 2 and cell_distance((3, 2), (1, 1)) == 2
    assert cell_distance((2, 7), (2, 7)) == 0


def test_a_report_on_a_diagonal_neighbour_finds_the_tumour_and_one_two_cells_off_does_not():
    found, hits = match_cells([(5, 5), (1, 4)], [(4, 4), (1, 2)], tolerance=1)
    assert found == [True, False] and hits == [1, 0]
    # each report claims the nearest tumour not claimed before: the second report of (4, 4) is a wrong report
    found, hits = match_cells([(4, 4), (4, 5)], [(4, 4), (7, 7)], tolerance=1)
    assert found == [True, False] and hits == [1, 0]
