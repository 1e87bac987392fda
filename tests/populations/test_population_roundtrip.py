"""The population file ``studyctl calibrate`` writes keeps the comments of the file it started from (they said
what the population is and where its numbers come from, and were lost, so a fit had to be carried into the
shipped file by hand), and reads back to exactly the fitted population."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from studyctl.populations.free import apply_values, free_params, mark_fitted
from studyctl.populations.loader import load_population_file, parse_population, shipped_population_path
from studyctl.workflows.calibrate import FIT_HEADER, population_text


def _fitted(path: Path):
    pop = load_population_file(path)
    free = free_params(pop, ["approach_speed_ratio", "recheck_mm.sd", "scan_read_s"])
    new = apply_values(pop, {"approach_speed_ratio": 3.123456789, "recheck_mm.sd": 0.7, "scan_read_s": 2.5}, free)
    new = mark_fitted(new, free, "studyctl calibrate to needle_insertion.targets.yaml")
    calibration = {"targets": "needle_insertion.targets.yaml", "free": [f.name for f in free],
                   # unchanged long inline lists: kept inline, re-wrapped by the writer
                   "used_for_fit": pop.calibration["used_for_fit"], "validation": pop.calibration["validation"],
                   "estimates": {"scan_read_s": {"value": 2.5, "se": 0.31, "identified": True}}}
    return replace(new, version=pop.version + 1, calibration=calibration, sha256="", path="")


def _comments(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if line.strip().startswith("#")]


def test_fitted_file_keeps_the_comments_and_reads_back_as_fitted(tmp_path):
    shipped = shipped_population_path("needle_insertion")
    source = tmp_path / "start.yaml"
    text = shipped.read_text(encoding="utf-8").replace("\nfixed:\n", "\n# the same for everyone\nfixed:\n")
    text = text.replace("  wall_n: 0.3\n", "  wall_n: 0.3  # an end-of-line comment\n")
    source.write_text(text, encoding="utf-8")
    pop = _fitted(source)
    text = population_text(source, pop)
    # every comment but an earlier fit's header line (replaced by the caller's new one)
    comments = [c for c in _comments(source.read_text(encoding="utf-8")) if not c.startswith(FIT_HEADER.strip())]
    assert len(comments) >= 5 and "wall_n: 0.3  # an end-of-line comment" in text
    assert _comments(text) == comments  # every comment, in order
    back = parse_population(text, "fitted")
    assert back.to_dict() == parse_population(pop.to_yaml(), "plain").to_dict()
    assert back.version == pop.version and back.fixed["approach_speed_ratio"] == 3.12346
    assert back.trait("recheck_mm").sd == 0.7 and back.trait("scan_read_s").source.startswith("FITTED")
    assert "note" not in back.calibration  # the new calibration block replaces the old one
    assert not [line for line in text.splitlines() if line.endswith(" ")]  # no trailing space from wrapped lists
    # a value that did not change keeps its text (here: its double quotes)
    assert '    source: "CHOSEN: lateral wobble of the hand set-point' in text


def test_an_earlier_fit_header_is_replaced_and_an_unreadable_source_falls_back(tmp_path):
    shipped = shipped_population_path("needle_insertion")
    source = tmp_path / "start.yaml"
    source.write_text(f"{FIT_HEADER}needle_insertion --free x\n" + shipped.read_text(encoding="utf-8"),
                      encoding="utf-8")
    pop = _fitted(source)
    assert FIT_HEADER not in population_text(source, pop)
    source.write_text("- not a mapping\n", encoding="utf-8")
    assert population_text(source, pop) == pop.to_yaml()
    assert population_text("", pop) == pop.to_yaml()
