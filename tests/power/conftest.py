"""Power-analysis fixtures: a small palpation study (tests/power/data) and one serial run shared by tests.

The small study keeps the seed-000 phantom, devices, controllers and virtual palpator but has a 3 x 3
grid and two conditions, so a replicate of 2-4 participants takes about a second of CPU.
"""

from __future__ import annotations

import pytest
from power_testdata import PLAN, PROTOCOL, REPLICATES, SEED, SIZES


@pytest.fixture(scope="session")
def mini_spec():
    from studyctl.power import prepare_power

    return prepare_power(PROTOCOL, PLAN, sizes=SIZES, replicates=REPLICATES, seed=SEED)


@pytest.fixture(scope="session")
def serial_run(mini_spec, tmp_path_factory):
    """The reference: every replicate run serially in this process."""
    from studyctl.workflows.power import run_power

    return run_power(mini_spec, tmp_path_factory.mktemp("serial"), workers=0)
