"""The analysis of one small stored study, pinned: tests, cells and the figures' data must not change.

A seeded simulated study (bio-inspired palpation, 2 virtual participants) is analysed end to end from
its database: metrics through the study reader, every test of the shipped plan, and the data of the
trace and controller figures. The outputs are compared byte for byte with the pinned files in
``tests/analysis/pinned/``. The same study with its stored scene truth removed (as databases written
before truth events) must give the same outputs through the rebuilt scenes.

The figures' data are pinned per platform (``tests/platform_pins.py``), the rest for every machine.
If the simulated study itself was meant to change (engine, participants, populations), re-pin with
``STUDYCTL_REPIN=1 pytest tests/analysis/test_pinned_output.py`` and say why in the commit.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sqlite3
from pathlib import Path

import pandas as pd
import pytest
from platform_pins import no_pin_here, platform_key

from studyctl.analysis import analyze, load_plan
from studyctl.workflows.simulate import simulate_study

pytestmark = pytest.mark.slow  # whole virtual sessions (run by CI with -m '')

PINNED = Path(__file__).parent / "pinned"
PROTOCOL = "bio_inspired_palpation"


def _csv(frame: pd.DataFrame) -> str:
    # 12 significant digits: more than the report's CSVs carry (10), fewer than the last-bit noise of an
    # iterative quantile (the studentized range) that differs between processes.
    return frame.to_csv(index=False, lineterminator="\n", float_format="%.12g")


def _outputs(workspace: Path) -> dict[str, str]:
    result = analyze(load_plan(PROTOCOL), workspace=workspace, figures=True)
    out = {
        "tests.csv": _csv(result.to_frame()),
        "cells.csv": _csv(result.tables["cells"]),
        "metrics.csv": _csv(result.data.frame),
    }
    figures = {}
    for fid, data in sorted(result.figures.items()):
        text = _csv(data.frame) + repr(sorted(data.meta.items())) + data.problem
        figures[fid] = {"rows": len(data.frame), "sha256": hashlib.sha256(text.encode()).hexdigest()}
    out["figures.json"] = json.dumps(figures, indent=1, sort_keys=True) + "\n"
    return out


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    ws = tmp_path_factory.mktemp("pinned") / "ws"
    simulate_study(PROTOCOL, 2, 7, ws)
    return ws


def _pinned_path(name: str) -> Path:
    # The figures' data are force traces to 12 digits: their last bits follow the platform (tests/platform_pins.py).
    # The tests, cells and metrics are the same on every machine.
    return PINNED / "figures" / f"{platform_key()}.json" if name == "figures.json" else PINNED / name


def test_analysis_of_a_stored_study_is_pinned(study):
    got = _outputs(study)
    assert json.loads(got["figures.json"]), "the plan's signal figures produced no data"
    if os.environ.get("STUDYCTL_REPIN") == "1":
        (PINNED / "figures").mkdir(parents=True, exist_ok=True)
        for name, text in got.items():
            _pinned_path(name).write_text(text)
    if not _pinned_path("figures.json").exists():
        no_pin_here("the figures' data", "tests/analysis/pinned/figures/")
        got.pop("figures.json")
    changed = [name for name, text in got.items() if _pinned_path(name).read_text() != text]
    assert not changed, (
        f"analysis output differs from tests/analysis/pinned/ in {', '.join(changed)}; if the simulated study "
        "was meant to change, re-pin with STUDYCTL_REPIN=1 (see this file's docstring)"
    )


def test_rebuilt_scene_truth_scores_the_same(study, tmp_path):
    ws = tmp_path / "old"
    shutil.copytree(study, ws)
    # An older database: no scene_truth events (events are append-only, so the copy drops the guard first).
    with sqlite3.connect(ws / "study.db") as con:
        con.execute("DROP TRIGGER event_no_delete")
        gone = con.execute("DELETE FROM event WHERE kind = 'scene_truth'").rowcount
    assert gone > 0
    assert _outputs(ws) == _outputs(study)
