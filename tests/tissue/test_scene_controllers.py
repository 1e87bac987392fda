"""The stiffness-tissue scene and the FF / PHF / PHF+FF controllers, through the simulated force device."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.controllers.tissue import PseudoHaptic, PseudoHapticForceFeedback, StiffnessMapForceFeedback
from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.errors import ModelParameterError
from studyctl.plugins.interfaces import Observation
from studyctl.scenes.tissue import StiffnessTissueScene

BASE = frozenset({"stiffness_map", "surface"})


def _scene(orientation=0.0, needs=BASE, **spec):
    return StiffnessTissueScene.build(spec, {"orientation_deg": orientation}, needs, np.random.default_rng(0))


def _obs(t, x, y, z):
    return Observation(t, {"x_mm": x, "y_mm": y, "z_mm": z})


def test_orientation_rotates_the_truth_about_the_block_centre():
    s0, s90 = _scene(0.0), _scene(90.0)
    a0 = s0.truth()["nodules"][0]
    a90 = s90.truth()["nodules"][0]
    assert (a0["x_mm"], a0["y_mm"]) == pytest.approx((30.0, 85.0))
    assert (a90["x_mm"], a90["y_mm"]) == pytest.approx((60 - 25.0, 60 + (30.0 - 60)))
    assert s90.truth()["orientation_deg"] == 90.0
    assert _scene(None).placement.rotation_deg == 0.0


def test_public_view_never_leaks_the_nodules():
    s = _scene(90.0, needs=BASE | {"view"})
    pub = s.public()
    assert set(pub) == {"surface", "start_mm"}
    assert "nodules" not in str(pub) and "nodule_count" not in pub
    assert _scene(tell_nodule_count=True).public()["nodule_count"] == 3
    heights = np.array(pub["surface"]["heights_mm"])
    assert np.nanmax(heights) == pytest.approx(25.0)


def test_deformation_view_is_built_only_when_a_view_is_shown():
    assert _scene().deformation is None
    s = _scene(needs=BASE | {"view"})
    assert s.deformation is not None
    frame = s.view({"cursor_x_mm": 60.0, "cursor_y_mm": 60.0, "cursor_z_mm": 21.0, "tissue_depth_mm": 4.0})
    assert frame["cursor_mm"] == (60.0, 60.0, 21.0)
    assert frame["deformation"].compute().depth_mm == 4.0
    display = frame["display"]
    assert display["orientation_deg"] == 0.0 and len(display["xs_mm"]) == len(display["heights_mm"]) == 61
    i, j, dz = frame["deformation"].compute().nodes[0]
    assert abs(display["xs_mm"][i] - 60.0) <= 20.0 and dz < 0
    assert "deformation" not in s.view({"x_mm": 60.0, "y_mm": 60.0, "z_mm": 30.0})


def test_bad_scene_specs():
    with pytest.raises(ModelParameterError, match="unknown field"):
        _scene(phantom_kind="x")
    with pytest.raises(ModelParameterError, match="phantom = 'jelly'"):
        _scene(phantom="jelly")
    with pytest.raises(ModelParameterError, match="needs field 'stiffness_map'"):
        _scene(phantom="measured")


def test_measured_phantom_from_files(tmp_path):
    block = _scene()
    block.stiffness.save_npz(tmp_path / "m.npz")
    s = _scene(
        phantom="measured",
        stiffness_map=str(tmp_path / "m.npz"),
        surface={"flat": {"x_mm": [0, 120], "y_mm": [0, 120], "height_mm": 25}},
        nodules=[{"name": "A", "x_mm": 30, "y_mm": 85, "diameter_mm": 10}],
    )
    assert s.truth()["nodules"][0]["name"] == "A"
    c = StiffnessMapForceFeedback({}, s)
    c.reset()
    assert c.step(_obs(0.0, 60.0, 60.0, 20.0))["fz_n"] == pytest.approx(
        StiffnessMapForceFeedback({}, block).step(_obs(0.0, 60.0, 60.0, 20.0))["fz_n"]
    )


def test_ff_pushes_out_of_the_tissue_and_publishes_the_avatar():
    c = StiffnessMapForceFeedback({}, _scene())
    c.reset()
    assert c.step(_obs(0.0, 60.0, 60.0, 26.0)) == {"fx_n": 0.0, "fy_n": 0.0, "fz_n": 0.0}
    cmd = c.step(_obs(0.001, 60.0, 60.0, 20.0))
    assert cmd["fz_n"] > 0.5 and abs(cmd["fx_n"]) < 1e-12
    d = c.diagnostics
    assert d["tissue_depth_mm"] == pytest.approx(5.0) and d["cursor_z_mm"] == 20.0
    assert d["tissue_normal_n"] == pytest.approx(cmd["fz_n"])


def test_controller_parameters_are_validated():
    s = _scene()
    with pytest.raises(ModelParameterError, match="unknown parameter 'max_force'"):
        StiffnessMapForceFeedback({"max_force": 3.0}, s)
    with pytest.raises(ModelParameterError, match="interpolation"):
        StiffnessMapForceFeedback({"interpolation": "bspline"}, s)
    with pytest.raises(ModelParameterError, match="r0"):
        PseudoHaptic({"r0": 0.0}, s)
    with pytest.raises(ModelParameterError, match="needs a stiffness_tissue scene"):
        StiffnessMapForceFeedback({}, None)
    assert "view" in PseudoHaptic.needs({}) and "view" not in StiffnessMapForceFeedback.needs({})


def _press(controller, depth_to=6.0, steps=300):
    controller.reset()
    out = []
    for k, z in enumerate(np.linspace(27.0, 25.0 - depth_to, steps)):
        out.append((controller.step(_obs(k * 0.001, 60.0, 60.0, float(z))), dict(controller.diagnostics)))
    return out


def test_phf_cursor_lags_the_hand_and_renders_no_force():
    out = _press(PseudoHaptic({}, _scene()))
    cmd, diag = out[-1]
    assert cmd == {"fx_n": 0.0, "fy_n": 0.0, "fz_n": 0.0}
    hand_depth, cursor_depth = 6.0, 25.0 - diag["cursor_z_mm"]
    assert 0.0 < cursor_depth < hand_depth - 1.0  # R_n = 1/(f_n + 1) slowed it down in the tissue
    assert diag["ratio_n"] == pytest.approx(1.0 / (diag["tissue_normal_n"] + 1.0), rel=0.05)
    steps = [abs(b[1]["cursor_z_mm"] - a[1]["cursor_z_mm"]) for a, b in zip(out, out[1:], strict=False)]
    assert max(steps) <= (27.0 - 19.0) / 299 + 1e-9  # never faster than the hand: no jumps


def test_phf_ff_renders_the_force_at_the_cursor():
    out_both = _press(PseudoHapticForceFeedback({}, _scene()))
    out_phf = _press(PseudoHaptic({}, _scene()))
    cmd, diag = out_both[-1]
    assert diag["cursor_z_mm"] == pytest.approx(out_phf[-1][1]["cursor_z_mm"])
    assert cmd["fz_n"] == pytest.approx(diag["tissue_normal_n"]) and cmd["fz_n"] > 0.2


def test_through_the_simulated_device_the_force_reaches_the_hand():
    scene = _scene()
    device = SimulatedForceDevice({"hand": "none"}, scene, np.random.default_rng(0))
    device.open()
    c = StiffnessMapForceFeedback({}, scene)
    c.reset()
    felt = []
    for k, z in enumerate(np.linspace(27.0, 20.0, 200)):
        device.apply_input({"x_mm": 60.0, "y_mm": 60.0, "z_mm": float(z)})
        obs = device.read(k * 0.001)
        device.write(c.step(obs))
        felt.append(device.feedback()["fz_n"])
    assert felt[0] == 0.0 and felt[-1] == pytest.approx(c.diagnostics["tissue_normal_n"], rel=1e-6)
    assert max(felt) <= 3.3 + 1e-12
    assert math.isclose(c.diagnostics["tissue_depth_mm"], 5.0, abs_tol=0.02)


def _frame_repr(frame):
    if frame is None:
        return None
    out = {k: v for k, v in frame.items() if k not in ("surface", "display", "deformation")}
    if "deformation" in frame:
        d = frame["deformation"].compute()
        out["deformation"] = (d.depth_mm, repr(d.nodes))
    return repr(out)


def test_view_parts_draws_the_frame_of_the_merged_channels():
    s = _scene(needs=BASE | {"view"})
    cases = [
        ({"x_mm": 60.0, "y_mm": 60.0, "z_mm": 30.0}, {}, {}),
        ({"x_mm": 1.0, "y_mm": 2.0, "z_mm": 3.0}, {"x_mm": 60.0, "y_mm": 61.0, "z_mm": 21.0}, {"tissue_depth_mm": 4.0}),
        # a later mapping wins: the controller's cursor over the handle, its contact point over the device's
        ({"x_mm": 1.0, "y_mm": 2.0, "z_mm": 3.0}, {"cursor_x_mm": 5.0, "cursor_y_mm": 5.0, "cursor_z_mm": 5.0,
                                                 "contact_x_mm": 0.0, "contact_y_mm": 0.0},
         {"cursor_x_mm": 60.0, "cursor_y_mm": 60.0, "cursor_z_mm": 21.0, "tissue_depth_mm": 3.0,
          "contact_x_mm": 10.0, "contact_y_mm": 12.0}),
        ({"x_mm": 60.0, "y_mm": 60.0}, {}, {}),  # no z: no cursor
        ({"x_mm": 60.0, "y_mm": 60.0, "z_mm": 20.0}, {"cursor_x_mm": None}, {"tissue_depth_mm": 2.0}),
    ]
    for a, b, c in cases:
        assert _frame_repr(s.view_parts(a, b, c)) == _frame_repr(s.view({**a, **b, **c}))
    assert "deformation" in s.view_parts(*cases[2])
