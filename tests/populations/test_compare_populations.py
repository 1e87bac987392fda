"""The landing rule script: summed squared z over seeds decides, not one seed's agreeing-target count."""

from pathlib import Path

import pytest
from population_testdata import load_script

HEADER = "target,role,z,agrees\n"


def _load():
    return load_script("compare_populations")


def _report(tmp_path: Path, name: str, rows: list[tuple[str, str, str, str]]) -> Path:
    d = tmp_path / name
    d.mkdir()
    (d / "agreement.csv").write_text(HEADER + "".join(",".join(r) + "\n" for r in rows))
    return d


def test_rule_sums_squared_z_over_seeds_and_counts_a_missing_z_as_the_penalty(tmp_path, capsys):
    mod = _load()
    # Seed 1: the candidate looks worse on fit (z 2 vs 1); seed 2 it is far better (1 vs missing = 25).
    b1 = _report(tmp_path, "b1", [("a", "fit", "1.0", "True"), ("v", "validation", "1.0", "True")])
    c1 = _report(tmp_path, "c1", [("a", "fit", "2.0", "False"), ("v", "validation", "0.5", "True")])
    b2 = _report(tmp_path, "b2", [("a", "fit", "", "False"), ("v", "validation", "1.0", "True")])
    c2 = _report(tmp_path, "c2", [("a", "fit", "1.0", "True"), ("v", "validation", "1.0", "True")])
    assert mod.figures(b2)["fit"]["z2"] == 25.0
    mod.main(["--base", str(b1), str(b2), "--candidate", str(c1), str(c2)])
    out = capsys.readouterr().out
    assert "fit 1/2 z2    26.0" in out and "fit 1/2 z2     5.0" in out
    assert out.rstrip().endswith("ship: True")
    # A candidate that loses an agreeing validation target does not ship, even with a lower validation z2.
    c3 = _report(tmp_path, "c3", [("a", "fit", "0.5", "True"), ("v", "validation", "0.1", "False")])
    mod.main(["--base", str(b1), "--candidate", str(c3)])
    assert capsys.readouterr().out.rstrip().endswith("ship: False")


def test_unpaired_or_missing_folders_are_refused_with_one_line(tmp_path):
    mod = _load()
    b1 = _report(tmp_path, "b1", [("a", "fit", "1.0", "True")])
    with pytest.raises(SystemExit, match="1 base folders but 2 candidate"):
        mod.main(["--base", str(b1), "--candidate", str(b1), str(b1)])
    with pytest.raises(SystemExit, match="agreement.csv not found"):
        mod.main(["--base", str(tmp_path), "--candidate", str(b1)])
