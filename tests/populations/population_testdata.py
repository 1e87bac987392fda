"""Paths and helpers shared by the population and calibration tests."""

from __future__ import annotations

from pathlib import Path

DATA = Path(__file__).parent / "data"
POPULATION = DATA / "palpator_small.yaml"
MINI_PROTOCOL = Path(__file__).parent.parent / "power" / "data" / "mini_palpation.yaml"
MINI_PLAN = Path(__file__).parent.parent / "power" / "data" / "mini_palpation_plan.yaml"


def write_variant(tmp_path: Path, old: str, new: str, source: Path = POPULATION) -> Path:
    """A copy of ``source`` with one piece of text replaced (a bad-input variant)."""
    text = source.read_text(encoding="utf-8")
    assert old in text, old
    out = tmp_path / f"variant{source.suffix}"
    out.write_text(text.replace(old, new, 1), encoding="utf-8")
    return out
