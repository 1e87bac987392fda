"""Frame encoding: the browser rebuilds exactly the image the scene rendered; tissue frames stay faithful."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.models.pseudo_haptics import deformation_profile_array
from studyctl.scenes.needle_liver import NeedleLiverScene
from studyctl.scenes.tissue import StiffnessTissueScene
from studyctl.view import encode
from studyctl.view.hub import FrameState, ViewHub


def test_grey_codec_round_trips_keys_and_deltas():
    rng = np.random.default_rng(1)
    codec = encode.GreyCodec()
    img = rng.integers(0, 256, (40, 60), dtype=np.uint8)
    key, frame = codec.encode(img)
    assert key is not None and key["key"] == frame["key"] == 1 and frame["changed"] == 0
    np.testing.assert_array_equal(encode.decode_grey(key, frame), img)
    nxt = img.copy()
    nxt[5, 7:30] = 255  # a needle
    none, frame2 = codec.encode(nxt)
    assert none is None and frame2["key"] == 1 and frame2["changed"] == int((nxt != img).sum())
    np.testing.assert_array_equal(encode.decode_grey(key, frame2), nxt)
    back, frame3 = codec.encode(img)  # the needle moved away again: a delta of nothing
    np.testing.assert_array_equal(encode.decode_grey(key, frame3), img)
    assert back is None and frame3["changed"] == 0
    other = rng.integers(0, 256, (40, 60), dtype=np.uint8)  # everything changed: a new key
    key2, frame4 = codec.encode(other)
    assert key2 is not None and key2["key"] == 2 and frame4["key"] == 2
    np.testing.assert_array_equal(encode.decode_grey(key2, frame4), other)
    key3, _ = codec.encode(np.zeros((10, 10), np.uint8))  # new shape: new key
    assert key3["key"] == 3 and (key3["w"], key3["h"]) == (10, 10)
    with pytest.raises(ValueError, match="2-D uint8"):
        codec.encode(np.zeros((3, 3), np.float64))


def test_ct_frames_decode_to_the_scene_render_at_every_pose():
    scene = NeedleLiverScene.build({}, {"sites": {"tumour": 5}}, frozenset({"view"}), np.random.default_rng(0))
    g = scene.geometry()
    inc, c = np.array(g.incision_mm), np.array(g.tumour_center_mm)
    out = (inc - c) / np.linalg.norm(inc - c)
    hub = ViewHub()
    key = None
    for i, depth in enumerate(np.linspace(-10.0, 60.0, 15)):
        tip = inc - out * depth
        frame = scene.view({"x_mm": tip[0], "y_mm": tip[1], "z_mm": tip[2], "dir_x": -out[0], "dir_y": -out[1],
                            "dir_z": -out[2]})
        msg, new_key = hub.encoded(FrameState(i + 1, 0.1 * i, 0.0, "view", frame, 0))
        key = new_key or key
        assert msg["kind"] == "ct" and msg["key"] == key["key"] and msg["seq"] == i + 1
        np.testing.assert_array_equal(encode.decode_grey(key, msg), frame["image"])
        assert msg["tip_mm"] == pytest.approx(list(tip)) and [p["name"] for p in msg["panels"]] == ["axial", "coronal"]
        assert msg["changed"] < 0.05 * frame["image"].size  # only the needle is sent
    assert key["key"] == 1  # one key image for the whole trial


def test_tissue_frame_profile_matches_the_deformation_model():
    spec = {"phantom": "seed003_block"}
    scene = StiffnessTissueScene.build(spec, {"orientation_deg": 30.0}, frozenset({"view"}), np.random.default_rng(0))
    frame = scene.view({"cursor_x_mm": 50.0, "cursor_y_mm": 60.0, "cursor_z_mm": 22.0, "tissue_depth_mm": 3.0,
                        "contact_x_mm": 52.0, "contact_y_mm": 61.0})
    msg = encode.tissue_message(frame)
    assert msg["cursor_mm"] == [50.0, 60.0, 22.0] and msg["depth_mm"] == 3.0 and msg["indenter_radius_mm"] == 5.0
    d = msg["deformation"]
    assert d["depth_mm"] == 3.0 and d["contact_radius_mm"] == pytest.approx(math.sqrt(2 * 5 * 3 - 9))
    rho = np.array([p[0] for p in d["profile"]])
    dz = np.array([p[1] for p in d["profile"]])
    assert rho[0] == 0.0 and dz[0] == -3.0 and np.all(np.diff(rho) > 0) and np.all(np.diff(dz) >= -1e-9)
    expected = -deformation_profile_array(rho, 3.0, 5.0, 20.0)
    # binned means of a smooth profile: within the change of the profile over one bin
    assert np.max(np.abs(dz - expected)) < 0.25
    surface = encode.surface_message(frame["surface"])
    flat = [v for row in surface["heights_mm"] for v in row]
    assert None in flat and all(v is None or v == pytest.approx(25.0) for v in flat)  # NaN off the rotated block
    out_of_contact = encode.tissue_message(scene.view({"cursor_x_mm": 50.0, "cursor_y_mm": 60.0,
                                                       "cursor_z_mm": 40.0, "tissue_depth_mm": 0.0}))
    assert out_of_contact["deformation"] is None


def test_other_scenes_show_their_numbers():
    msg = encode.generic_message({"x": 1, "y": np.float64(2.5), "name": "a", "bad": float("nan"), "flag": True})
    assert msg == {"kind": "values", "values": {"x": 1.0, "y": 2.5}}
    assert encode.frame_kind({"x": 1.0}) == "values"
