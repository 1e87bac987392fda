"""Cells of a palpation report grid, (column, row): how far apart two cells are.

Seed 000 counts a tumour as found when a report lies "within 1 grid cell" of it, diagonals included: the chessboard
(Chebyshev) distance, the larger of the column and row steps. The metric (`analysis.metrics.match_cells`), the virtual
palpator (which keeps only the strongest of neighbouring cells, and practises on cells clear of the marks) and the
scripts that count wrong reports all ask this one question, so it is written once, here, below all of them.
"""

from __future__ import annotations

from collections.abc import Sequence


def cell_distance(a: Sequence[float], b: Sequence[float]) -> float:
    """Chebyshev distance between cells ``a`` and ``b`` (column, row): 1 for an edge or a corner neighbour."""
    return max(abs(a[0] - b[0]), abs(a[1] - b[1]))


def within_one_cell(a: Sequence[float], b: Sequence[float]) -> bool:
    """Is ``b`` the cell ``a`` or one of its eight neighbours (seed 000's rule for a correct report)?"""
    return cell_distance(a, b) <= 1


__all__ = ["cell_distance", "within_one_cell"]
