"""Turn the scene's view frames into the small JSON messages the participant's browser draws.

Pure functions and one codec object; no I/O. Three kinds of frame reach the view:

* **CT** (:class:`studyctl.scenes.needle_liver.CTFrame`, ``kind == "ct"``): an 8-bit grey image of two
  slices. Within a trial only the needle pixels change, so :class:`GreyCodec` sends one *key* image and then,
  per frame, the pixels that differ from it (index + value). Lossless: the browser rebuilds exactly the
  image the scene rendered.
* **Tissue** (:meth:`studyctl.scenes.tissue.StiffnessTissueScene.view`): a static surface (sent once per
  trial) plus, per frame, the cursor, its depth and the deformation around the contact as a radial profile.
* **Anything else** (third-party scenes): its finite numbers, shown as a read-out.
"""

from __future__ import annotations

import base64
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from studyctl.errors import UsageError

# A delta larger than this share of the pixels is sent as a new key image instead.
DELTA_MAX_SHARE = 0.25
PROFILE_BIN_MM = 0.5


def b64(data: bytes | np.ndarray) -> str:
    if isinstance(data, np.ndarray):
        data = np.ascontiguousarray(data).tobytes()
    return base64.b64encode(data).decode("ascii")


class GreyCodec:
    """Key image + sparse deltas for 8-bit grey images of a fixed shape (one codec per trial).

    :meth:`encode` returns ``(key, frame)``: ``key`` is a new key-image message (or None when the current
    key still serves) and ``frame`` names the key it applies to and lists the differing pixels as
    little-endian uint32 flat indices and uint8 values (base64).
    """

    def __init__(self) -> None:
        self.key_id = 0
        self._key: np.ndarray | None = None

    @property
    def key_message(self) -> dict[str, Any] | None:
        """The current key image (sent to a browser that (re)connects mid-trial)."""
        if self._key is None:
            return None
        h, w = self._key.shape
        return {"key": self.key_id, "w": int(w), "h": int(h), "data": b64(self._key)}

    def encode(self, image: np.ndarray) -> tuple[dict[str, Any] | None, dict[str, Any]]:
        img = np.asarray(image)
        if img.dtype != np.uint8 or img.ndim != 2:
            raise UsageError(f"grey codec: expected a 2-D uint8 image, got {img.dtype} with shape {img.shape}")
        new_key = None
        if self._key is None or self._key.shape != img.shape:
            idx = None
        else:
            idx = np.flatnonzero(img.ravel() != self._key.ravel())
            if idx.size > DELTA_MAX_SHARE * img.size:
                idx = None
        if idx is None:
            self._key = img.copy()
            self.key_id += 1
            new_key = self.key_message
            idx = np.empty(0, dtype=np.int64)
        frame = {
            "key": self.key_id,
            "didx": b64(idx.astype("<u4")),
            "dval": b64(img.ravel()[idx]),
            "changed": int(idx.size),
        }
        return new_key, frame


def decode_grey(key: Mapping[str, Any], frame: Mapping[str, Any]) -> np.ndarray:
    """Rebuild the image a browser draws from a key message and a frame (the JavaScript does the same)."""
    w, h = int(key["w"]), int(key["h"])
    img = np.frombuffer(base64.b64decode(key["data"]), dtype=np.uint8).copy()
    idx = np.frombuffer(base64.b64decode(frame["didx"]), dtype="<u4")
    val = np.frombuffer(base64.b64decode(frame["dval"]), dtype=np.uint8)
    img[idx] = val
    return img.reshape(h, w)


def _floats(values: Any) -> list[float] | None:
    if values is None:
        return None
    return [float(v) for v in values]


def ct_message(frame: Mapping[str, Any], codec: GreyCodec) -> tuple[dict[str, Any] | None, dict[str, Any]]:
    """(key image or None, frame message) for a CT frame: image delta, slice geometry and needle pose."""
    key, msg = codec.encode(np.asarray(frame["image"]))
    panels = []
    for p in frame.get("panels") or ():
        panels.append({k: (float(v) if isinstance(v, (int, float, np.floating, np.integer)) else v)
                       for k, v in p.items()})
    msg.update({"kind": "ct", "panels": panels, "tip_mm": _floats(frame.get("tip_mm")),
                "axis": _floats(frame.get("axis"))})
    return key, msg


def surface_message(surface: Mapping[str, Any]) -> dict[str, Any]:
    """The static tissue surface (device frame) as rows of heights; NaN (off the tissue) becomes null."""
    heights = np.asarray(surface["heights_mm"], dtype=float)
    rows = [[None if not math.isfinite(v) else round(float(v), 3) for v in row] for row in heights]
    return {
        "xs_mm": [round(float(v), 4) for v in surface["xs_mm"]],
        "ys_mm": [round(float(v), 4) for v in surface["ys_mm"]],
        "heights_mm": rows,
    }


def radial_profile(pending: Any, display: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """The deformation around the contact as ``[[ρ mm, dz mm], …]`` (binned), from a pending frame.

    ``display`` is the scene's display grid (``xs_mm``, ``ys_mm`` in the tissue frame) the node indices
    refer to. The display is radially symmetric about the contact (seed 003 §2.3), so a radial profile
    draws it in any frame (the tissue's orientation does not matter) and is a few dozen numbers, not a mesh.
    """
    if pending is None:
        return None
    frame = pending.compute()
    radius = display.get("indenter_radius_mm") if display else None
    profile: list[list[float]] = []
    if display and frame.nodes:
        xs = np.asarray(display["xs_mm"], dtype=float)
        ys = np.asarray(display["ys_mm"], dtype=float)
        nodes = np.asarray(frame.nodes, dtype=float)
        ii = nodes[:, 0].astype(int)
        jj = nodes[:, 1].astype(int)
        rho = np.hypot(xs[ii] - frame.center_mm[0], ys[jj] - frame.center_mm[1])
        dz = nodes[:, 2]
        bins = np.floor(rho / PROFILE_BIN_MM).astype(int)
        for b in np.unique(bins):
            sel = bins == b
            profile.append([round(float(rho[sel].mean()), 3), round(float(dz[sel].mean()), 4)])
        if profile and profile[0][0] > 0.0:
            # the contact rarely sits on a grid node; the model's displacement there is the full depth
            profile.insert(0, [0.0, -round(float(frame.depth_mm), 4)])
    return {
        "depth_mm": float(frame.depth_mm),
        "contact_radius_mm": float(frame.contact_radius_mm),
        "range": frame.range,
        "indenter_radius_mm": float(radius) if radius else None,
        "profile": profile,
    }


def tissue_message(frame: Mapping[str, Any]) -> dict[str, Any]:
    cursor = frame.get("cursor_mm")
    display = frame.get("display")
    radius = display.get("indenter_radius_mm") if display else None
    return {
        "kind": "tissue",
        "cursor_mm": _floats(cursor),
        "depth_mm": float(frame.get("depth_mm", 0.0) or 0.0),
        "indenter_radius_mm": float(radius) if radius else None,
        "deformation": radial_profile(frame.get("deformation"), display),
    }


def generic_message(frame: Mapping[str, Any]) -> dict[str, Any]:
    """A third-party scene's frame: its finite scalar values, shown as a read-out."""
    values = {}
    for k, v in frame.items():
        if isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool) and math.isfinite(v):
            values[str(k)] = float(v)
        if len(values) >= 24:
            break
    return {"kind": "values", "values": values}


def frame_kind(frame: Mapping[str, Any]) -> str:
    if frame.get("kind") == "ct" and "image" in frame:
        return "ct"
    if "surface" in frame and "cursor_mm" in frame:
        return "tissue"
    return "values"
