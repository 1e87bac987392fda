"""The README's demo block names each shipped population by version and sha256: a shipped file edited without
re-running that block (a note added beside a trait changes the bytes, so the sha256 every new session stores)
fails here, since a reader compares the printed sha256 with their own run's."""

from __future__ import annotations

import re
from pathlib import Path

from studyctl.populations.loader import load_population_file, shipped_population_path

README = Path(__file__).resolve().parents[2] / "README.md"
LINE = re.compile(r"^  (\w+): population: (\w+) v(\d+) \(shipped[^;]*; sha256 ([0-9a-f]{12}); \d+ traits\)$")


def test_the_demo_block_names_the_shipped_populations_as_they_are():
    printed = [m.groups() for m in map(LINE.match, README.read_text(encoding="utf-8").splitlines()) if m]
    assert {study for study, *_ in printed} == {"bio_inspired_palpation", "needle_insertion", "data_driven_palpation",
                                                "pseudo_haptic_palpation"}
    for study, name, version, sha in printed:
        pop = load_population_file(shipped_population_path(study))
        assert (name, int(version), sha) == (pop.name, pop.version, pop.sha256[:12]), study
