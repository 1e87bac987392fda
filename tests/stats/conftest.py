"""Reference data for the statistics tests (see tests/reference/stats/)."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import pandas as pd
import pytest

REF = Path(__file__).resolve().parents[1] / "reference" / "stats"


def _load(name: str) -> dict[tuple[str, str], float]:
    df = pd.read_csv(REF / name, comment="#", dtype=str)
    vals = df["value"].str.strip().replace({"NA": "nan", "Inf": "inf", "-Inf": "-inf"})
    return {(c, k): float(v) for c, k, v in zip(df["case"], df["key"], vals, strict=True)}


@pytest.fixture(scope="session")
def rref() -> dict[tuple[str, str], float]:
    return _load("r_reference.csv")


@pytest.fixture(scope="session")
def xref() -> dict[tuple[str, str], float]:
    return _load("exact_reference.csv")


@pytest.fixture(scope="session")
def data() -> dict[str, dict[str, list[float]]]:
    df = pd.read_csv(REF / "inputs.csv")
    out: dict[str, dict[str, list[float]]] = defaultdict(dict)
    for (ds, g), sub in df.groupby(["dataset", "group"], sort=False):
        out[ds][g] = sub["value"].tolist()
    return out
