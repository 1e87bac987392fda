"""Paths and helpers shared by the population and calibration tests."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

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


def load_script(name: str) -> ModuleType:
    """The developers' script ``scripts/<name>.py`` as a module (the scripts folder is not a package)."""
    path = Path(__file__).resolve().parents[2] / "scripts" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
