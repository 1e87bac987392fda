"""Liver scene, CT view and its reader, the simulated 3-DoF device and the omega.6 adapter."""

from __future__ import annotations

import math
import sys
import types

import numpy as np
import pytest

from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.devices.omega import Omega6Device
from studyctl.errors import DeviceError, ModelParameterError
from studyctl.participants.ct_reader import read_ct
from studyctl.scenes.needle_liver import NEEDLE_LEVEL, NeedleLiverScene


# ---------------------------------------------------------------- scene
def test_sites_are_deterministic_and_distinct():
    a = NeedleLiverScene.build({}, {"sites": {"tumour": 3}}, frozenset(), np.random.default_rng(1))
    b = NeedleLiverScene.build({}, {"sites": {"tumour": 3}}, frozenset(), np.random.default_rng(99))
    c = NeedleLiverScene.build({}, {"sites": {"tumour": 4}}, frozenset(), np.random.default_rng(1))
    assert a.truth() == b.truth()  # the stored site alone rebuilds the trial's geometry
    assert a.truth() != c.truth()
    g = a.geometry()
    assert g.tumour_radius_mm == 1.25  # 2.5 mm tumour
    assert g.planned_length_mm == pytest.approx(55.0)
    assert math.dist(g.incision_mm, g.liver_center_mm) == pytest.approx(g.liver_radius_mm)
    # the incision lies within the approach cone about +z
    d = np.array(g.incision_mm) - np.array(g.tumour_center_mm)
    assert d[2] / np.linalg.norm(d) >= math.cos(math.radians(35)) - 1e-9


def test_placement_explicit_or_drawn_and_bad_spec_errors():
    placement = NeedleLiverScene.place({}, np.random.default_rng(5))
    s1 = NeedleLiverScene.build({}, placement, frozenset(), np.random.default_rng(0))
    assert s1.truth()["tumour_center_mm"] == pytest.approx(placement["tumour_center_mm"])
    drawn = NeedleLiverScene.build({}, {"sites": None, "orientation_deg": None}, frozenset(), np.random.default_rng(7))
    again = NeedleLiverScene.build({}, {}, frozenset(), np.random.default_rng(7))
    assert drawn.truth() == again.truth()  # drawn from the trial's seeded stream
    with pytest.raises(ModelParameterError, match="unknown field"):
        NeedleLiverScene.build({"liver_radius": 3}, {}, frozenset(), np.random.default_rng(0))
    with pytest.raises(ModelParameterError, match="tumour_diameter_mm"):
        NeedleLiverScene.build({"tumour_diameter_mm": -1}, {}, frozenset(), np.random.default_rng(0))
    with pytest.raises(ModelParameterError, match="approach_dir"):
        NeedleLiverScene.build({}, {"tumour_center_mm": [0, 0, 0]}, frozenset(), np.random.default_rng(0))


def test_view_is_built_only_when_needed(scene):
    bare = NeedleLiverScene.build({}, {"sites": {"tumour": 1}}, frozenset({"layers"}), np.random.default_rng(0))
    assert bare.view({"x_mm": 0.0, "y_mm": 0.0, "z_mm": 30.0}) is None
    assert bare._renderer is None
    assert scene.view({"x_mm": 0.0, "y_mm": 0.0, "z_mm": 30.0}) is not None
    assert scene.sense({"x_mm": 0.0}) == {}


def test_ct_frame_shows_needle_relative_to_tumour_and_reader_recovers_them(scene):
    g = scene.geometry()
    a, u = np.array(g.incision_mm), np.array(g.planned_direction)
    rng = np.random.default_rng(2)
    for s in (-15.0, 10.0, 40.0, 53.0):
        tip = a + s * u + rng.normal(0.0, 1.5, 3)
        frame = scene.view({"x_mm": tip[0], "y_mm": tip[1], "z_mm": tip[2], "needle_dir_x": u[0],
                            "needle_dir_y": u[1], "needle_dir_z": u[2]})  # fmt: skip
        image = frame["image"]
        assert image.dtype == np.uint8 and image.shape == frame["shape"]
        assert (image == NEEDLE_LEVEL).sum() > 50
        reading = read_ct(frame, u)
        assert np.linalg.norm(np.array(reading.tip_mm) - tip) < 0.6  # half-pixel quantisation
        if s < 50:  # the tumour is hidden under the needle's projection once the tip reaches it
            assert np.linalg.norm(np.array(reading.tumour_mm) - np.array(g.tumour_center_mm)) < 0.3
        assert np.linalg.norm(np.array(reading.marker_mm) - a) < 0.6
    # the frame is lazy and a Mapping
    lazy = scene.view({"x_mm": 0.0, "y_mm": 0.0, "z_mm": 30.0})
    assert lazy._image is None and set(lazy) >= {"image", "panels", "kind"} and lazy["kind"] == "ct"


# ---------------------------------------------------------------- simulated device
def _open(params=None, scene=None):
    dev = SimulatedForceDevice(params or {}, scene)
    dev.open()
    return dev


@pytest.mark.parametrize("cls, cap", [("omni", 3.3), ("omega6", 12.0)])
def test_force_is_clamped_to_the_device_maximum(cls, cap):
    dev = _open({"device_class": cls})
    dev.apply_input({"x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0})
    dev.read(0.0)
    dev.write({"fx_n": 30.0, "fy_n": 40.0, "fz_n": 0.0})
    f = dev.feedback()
    assert math.hypot(f["fx_n"], f["fy_n"], f["fz_n"]) == pytest.approx(cap)
    assert f["fx_n"] / f["fy_n"] == pytest.approx(0.75)  # direction kept
    assert dev.limits.max_force_n == cap


def test_forces_push_the_simulated_hand():
    dev = _open()
    dev.apply_input({"x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0})
    dev.read(0.0)
    for k in range(1, 3000):
        dev.write({"fx_n": 0.6, "fy_n": 0.0, "fz_n": 0.0})
        dev.read(k * 1e-3)
    # equilibrium of the hand spring (300 N/m): 0.6 N / 300 N/m = 2 mm
    assert dev.feedback()["x_mm"] == pytest.approx(2.0, abs=0.02)


def test_still_hand_velocity_noise_is_inside_the_stick_band():
    dev = _open()
    dev.apply_input({"x_mm": 0.004, "y_mm": 0.0, "z_mm": 0.0})
    speeds = []
    for k in range(2000):
        dev.apply_input({"x_mm": 0.004 + 0.006 * math.sin(k * 0.37), "y_mm": 0.0, "z_mm": 0.0})
        dev.write({"fx_n": 0.0})
        o = dev.read(k * 1e-3).values
        speeds.append(abs(o["vx_mm_s"]))
    assert max(speeds[100:]) < 2.0  # the controller's default stick band


def test_nan_or_jump_puts_the_device_in_its_safe_state():
    dev = _open({"hand": "none"})
    dev.apply_input({"x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0})
    dev.read(0.0)
    dev.apply_input({"x_mm": 30.0, "y_mm": 0.0, "z_mm": 0.0})  # 30 mm in one tick
    o = dev.read(0.001)
    assert "jumped" in dev.fault and o.faults == (dev.fault,)
    dev.write({"fx_n": 1.0, "fy_n": 1.0, "fz_n": 1.0})
    assert dev.feedback()["fx_n"] == 0.0  # latched: no force after the fault
    dev2 = _open()
    dev2.apply_input({"x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0})
    dev2.read(0.0)
    dev2.apply_input({"x_mm": float("nan"), "y_mm": 0.0, "z_mm": 0.0})
    assert dev2.read(0.001).faults and "non-finite" in dev2.fault
    dev2.close()
    dev2.close()  # safe twice


def test_device_parameter_errors():
    with pytest.raises(ModelParameterError, match="unknown parameter"):
        SimulatedForceDevice({"maxforce": 3})
    with pytest.raises(ModelParameterError, match="device_class"):
        SimulatedForceDevice({"device_class": "falcon"})
    with pytest.raises(ModelParameterError, match="hand_mass_kg"):
        SimulatedForceDevice({"hand_mass_kg": 0})


# ---------------------------------------------------------------- omega.6 adapter
def test_missing_sdk_names_the_extra(monkeypatch):
    # import fails as if not installed, whatever an earlier test left loaded (an emulated stand-in's submodules
    # stay in sys.modules and a cached `forcedimension_core.dhd` would be found without its parent)
    for name in [m for m in sys.modules if m.startswith("forcedimension_core.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "forcedimension_core", None)
    dev = Omega6Device({})
    with pytest.raises(DeviceError, match=r"studyctl\[omega\]"):
        dev.open()


class _FakeDhd(types.ModuleType):
    """Stands in for forcedimension_core.dhd: metres, a rotated wrist, button 0 pressed."""

    def __init__(self) -> None:
        super().__init__("forcedimension_core.dhd")
        self.forces: list[list[float]] = []
        self.calls: list[str] = []
        self.expert = types.SimpleNamespace(setWatchdog=lambda v, ID=-1: self.calls.append(f"watchdog {v}") or 0)

    def open(self):
        return 0

    def openID(self, i):
        return i

    def errorGetLastStr(self):
        return "fake error"

    def setMaxForce(self, f, ID=-1):
        self.calls.append(f"max {f}")
        return 0

    def enableForce(self, on, ID=-1):
        self.calls.append(f"force {on}")
        return 0

    def getPosition(self, out, ID=-1):
        out[:] = [0.01, -0.02, 0.03]
        return 0

    def getLinearVelocity(self, out, ID=-1):
        out[:] = [0.001, 0.0, -0.002]
        return 0

    def getOrientationFrame(self, out, ID=-1):
        out[0][:] = [0.0, 0.0, 1.0]
        out[1][:] = [0.0, 1.0, 0.0]
        out[2][:] = [-1.0, 0.0, 0.0]
        return 0

    def getButton(self, index=0, ID=-1):
        return 1

    def setForce(self, f, ID=-1):
        self.forces.append(list(f))
        return 0

    def close(self, ID=-1):
        self.calls.append("close")
        return 0


def test_omega_adapter_converts_units_and_frames(monkeypatch):
    fake = _FakeDhd()
    pkg = types.ModuleType("forcedimension_core")
    pkg.dhd = fake
    monkeypatch.setitem(sys.modules, "forcedimension_core", pkg)
    monkeypatch.setitem(sys.modules, "forcedimension_core.dhd", fake)
    dev = Omega6Device({"pen_axis": "-x", "offset_mm": [0.0, 0.0, -10.0]})
    dev.open()
    assert "max 12.0" in fake.calls and "force True" in fake.calls and "watchdog 80" in fake.calls
    v = dev.read(0.5).values
    assert (v["x_mm"], v["y_mm"], v["z_mm"]) == pytest.approx((10.0, -20.0, 20.0))
    assert (v["vx_mm_s"], v["vz_mm_s"]) == pytest.approx((1.0, -2.0))
    assert (v["dir_x"], v["dir_y"], v["dir_z"]) == pytest.approx((-0.0, -0.0, 1.0))
    assert v["button"] == 1.0
    dev.write({"fx_n": 0.5, "fy_n": -0.25, "fz_n": 1.0})
    assert fake.forces[-1] == [0.5, -0.25, 1.0]
    dev.close()
    dev.close()
    assert fake.forces[-1] == [0.0, 0.0, 0.0] and fake.calls[-1] == "close"
    with pytest.raises(ModelParameterError, match="max_force_n"):
        Omega6Device({"max_force_n": 20})
    with pytest.raises(ModelParameterError, match="pen_axis"):
        Omega6Device({"pen_axis": "w"})
