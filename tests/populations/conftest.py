"""Population tests: a small population of the virtual palpator and the power tests' small palpation study."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

HERE = str(Path(__file__).parent)
if HERE not in sys.path:  # importlib mode: make population_testdata importable from the test modules
    sys.path.insert(0, HERE)

from population_testdata import POPULATION  # noqa: E402


@pytest.fixture
def population():
    from studyctl.populations import load_population_file

    return load_population_file(POPULATION)
