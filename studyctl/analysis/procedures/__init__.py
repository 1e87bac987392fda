"""The analysis tests as a registry: one :class:`TestSpec` per test, by name.

A new test is a function ``run(cell) -> [Finding]`` reading its result through ``summary()`` (or
``pairs()``) and one :class:`TestSpec` in a module's ``SPECS``; the plan validator, the runner and the
report find it here. Kinds of data (``design``) and how often a test runs per cell (``each``) are the
constants of :mod:`studyctl.analysis.procedures.spec`.
"""

from __future__ import annotations

from studyctl.analysis.procedures import counts, means, models, ranks, tables
from studyctl.analysis.procedures.spec import (
    BETWEEN,
    DESCRIPTIVE,
    EACH_CELL,
    EACH_LEVEL,
    EACH_PAIR,
    PROPORTION,
    WITHIN,
    Cell,
    Finding,
    TestSpec,
)
from studyctl.analysis.procedures.tables import describe

REGISTRY: dict[str, TestSpec] = {s.name: s for module in (ranks, means, counts, models, tables) for s in module.SPECS}

__all__ = [
    "BETWEEN",
    "DESCRIPTIVE",
    "EACH_CELL",
    "EACH_LEVEL",
    "EACH_PAIR",
    "PROPORTION",
    "REGISTRY",
    "WITHIN",
    "Cell",
    "Finding",
    "TestSpec",
    "describe",
]
