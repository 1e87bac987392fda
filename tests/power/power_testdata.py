"""Paths and settings of the small palpation study the power tests simulate (see conftest.py)."""

from pathlib import Path

DATA = Path(__file__).parent / "data"
PROTOCOL = DATA / "mini_palpation.yaml"
PLAN = DATA / "mini_palpation_plan.yaml"
SIZES = (2, 4)
REPLICATES = 2
SEED = 20261122
