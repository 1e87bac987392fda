"""Fixtures for the needle-insertion tests (seed 001); makes ``needle_helpers`` importable."""

from __future__ import annotations

import numpy as np
import pytest

from studyctl.models.needle_guidance import NeedleGeometry
from studyctl.scenes.needle_liver import NeedleLiverScene


@pytest.fixture
def vertical_geometry() -> NeedleGeometry:
    """Liver sphere of radius 55 mm centred on the tumour at (0, 0, −25); incision straight above."""
    return NeedleGeometry((0.0, 0.0, -25.0), 55.0, (0.0, 0.0, -25.0), 1.25, (0.0, 0.0, 30.0))


@pytest.fixture
def scene() -> NeedleLiverScene:
    return NeedleLiverScene.build({}, {"sites": {"tumour": 1}}, frozenset({"layers", "view"}), np.random.default_rng(0))
