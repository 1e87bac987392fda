"""Population tests: a small population of the virtual palpator and the power tests' small palpation study."""

from __future__ import annotations

import pytest
from population_testdata import POPULATION


@pytest.fixture
def population():
    from studyctl.populations import load_population_file

    return load_population_file(POPULATION)
