"""`protocol check` refuses plugin parameter values from the plugins' declared parameters, with file:line, before
any trial builds a plugin."""

from __future__ import annotations

from pathlib import Path

import pytest

from studyctl.cli.app import main
from studyctl.protocol import check_protocol, load_protocol, resolve_protocol

SHIPPED = ("bio_inspired_palpation", "needle_insertion", "data_driven_palpation", "pseudo_haptic_palpation")


def _edited(tmp_path: Path, name: str, *edits: tuple[str, str]) -> Path:
    text = resolve_protocol(name).read_text(encoding="utf-8")
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / f"{name}.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def _line_of(path: Path, needle: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), start=1) if needle in line)


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_protocols_pass(name):
    assert check_protocol(resolve_protocol(name)) == []


def test_controller_device_scene_values_are_checked_with_their_line(tmp_path):
    path = _edited(
        tmp_path,
        "bio_inspired_palpation",
        ("    controller: linear\n", "    controller: linear\n    params: {window_s: 9, windw: 1}\n"),
        ("  simulated: {plugin: sim_palpation}", "  simulated: {plugin: sim_palpation, params: {ramp_up_s: -1}}"),
        ("  plugin: sponge_phantom\n", "  plugin: sponge_phantom\n  params: {holes: true}\n"),
    )
    problems = [str(p) for p in check_protocol(path)]
    assert len(problems) == 4, problems
    line = _line_of(path, "window_s: 9")
    assert any(p.startswith(f"{path}:{line}:") and "conditions[2].params.window_s: controller 'linear': out of range:"
               " found 9, allowed a float in [0, 5] s" in p for p in problems), problems
    assert any("params.windw" in p and "did you mean 'window_s'?" in p for p in problems), problems
    assert any("devices.simulated.params.ramp_up_s: device 'sim_palpation': out of range: found -1" in p
               for p in problems), problems
    assert any("scene.params.holes: scene 'sponge_phantom': unknown parameter" in p and "'holes_mm'" in p
               for p in problems), problems


def test_scene_params_and_the_rules_between_them_are_checked_with_their_line(tmp_path):
    bad = "  plugin: needle_liver\n  params: {approach_max_deg: 95, liver_radius: 3}\n"
    needle = _edited(tmp_path, "needle_insertion", ("  plugin: needle_liver\n", bad))
    problems = [str(p) for p in check_protocol(needle)]
    line = _line_of(needle, "approach_max_deg: 95")
    assert len(problems) == 2, problems
    assert any(p.startswith(f"{needle}:{line}:") and "scene.params.approach_max_deg: scene 'needle_liver': out of "
               "range: found 95, allowed a float in [0, 80] deg" in p for p in problems), problems
    assert any("scene.params.liver_radius" in p and "did you mean 'liver_radius_mm'?" in p for p in problems), problems
    inside = _edited(tmp_path, "needle_insertion",
                     ("  plugin: needle_liver\n", "  plugin: needle_liver\n  params: {tumour_diameter_mm: 60}\n"))
    (problem,) = [str(p) for p in check_protocol(inside)]
    assert "scene.params.tumour_diameter_mm" in problem and "must be smaller than liver_radius_mm" in problem
    tissue = _edited(tmp_path, "data_driven_palpation", ("    phantom: seed002_curved", "    phantom: measured"))
    (problem,) = [str(p) for p in check_protocol(tissue)]
    assert problem.startswith(f"{tissue}:{_line_of(tissue, 'phantom: measured')}:"), problem
    assert "scene 'stiffness_tissue'" in problem and "needs field 'stiffness_map'" in problem
    thin = "  plugin: sponge_phantom\n  params: {size_mm: [140, 140, 20], tumour_height_mm: 25}\n"
    sponge = _edited(tmp_path, "bio_inspired_palpation", ("  plugin: sponge_phantom\n", thin))
    sponge_problems = [str(p) for p in check_protocol(sponge)]
    assert len(sponge_problems) == 1 and "scene.params.tumour_height_mm" in sponge_problems[0], sponge_problems


def test_needle_blocks_are_checked_at_the_key_that_holds_the_value(tmp_path):
    path = _edited(
        tmp_path,
        "needle_insertion",
        ("      radial: {k_p: 1000, k_d: 70}", "      radial: {k_p: 1000, k_d: 0.1}"),
        ("      liver: *liver\n", "      liver: {k_cutt: 5, f_dynamic: 0.8, f_static: 1.0, c: ten}\n"),
    )
    problems = [str(p) for p in check_protocol(path)]
    assert len(problems) == 3, problems
    bad_block = _line_of(path, "k_cutt")
    assert any(p.startswith(f"{path}:{bad_block}:") and "params.liver.k_cutt" in p and "did you mean 'k_cut'?" in p
               and "allowed one of 'c', 'f_dynamic', 'f_static', 'k_cut'" in p for p in problems), problems
    assert any("params.liver.c: controller 'needle_hybrid': not a number: found 'ten'" in p for p in problems)
    passivity = _line_of(path, "k_d: 0.1")
    assert any(p.startswith(f"{path}:{passivity}:") and "params.radial.k_d" in p and "K·T/2" in p
               for p in problems), problems


def test_the_cli_prints_one_error_and_writes_nothing(tmp_path, capsys):
    path = _edited(
        tmp_path, "data_driven_palpation", ("  simulated: {plugin: ", "  simulated: {params: {bogus: 1}, plugin: ")
    )
    assert main(["protocol", "check", str(path)]) != 0
    err = capsys.readouterr().err
    assert err.startswith("Error: ") and "Traceback" not in err and "bogus" in err
    with pytest.raises(Exception, match="bogus"):
        load_protocol(path)
