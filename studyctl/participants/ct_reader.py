"""How a virtual operator reads a CT-like frame: find the tumour, the skin marker and the needle tip.

Works on the frame's pixels only (``image`` and the ``panels`` pixel ↔ mm mapping), the way a person
reads the screen: grey-level bands tell metal from tumour from marker, and a location comes from pixel
centroids, so it carries the image's half-pixel quantisation. Never reads the scene's truth.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

# Grey-level bands (see studyctl.scenes.needle_liver): tumour ≈ 200 ± 12, marker 235, needle 255.
TUMOUR_BAND = (180, 222)
MARKER_BAND = (228, 245)
NEEDLE_MIN = 250


@dataclass(frozen=True)
class CTReading:
    """What one frame shows, in device millimetres (None where a structure is not visible)."""

    tumour_mm: tuple[float, float, float] | None
    marker_mm: tuple[float, float, float] | None
    tip_mm: tuple[float, float, float] | None


def _to_mm(panel: Mapping[str, Any], col: float, row: float) -> tuple[float, float]:
    size, mpp = panel["size_px"], panel["mm_per_px"]
    return (
        panel["center_h_mm"] + (col - size / 2 + 0.5) * mpp,
        panel["center_v_mm"] - (row - size / 2 + 0.5) * mpp,
    )


def _combine(parts: list[tuple[Mapping[str, Any], float, float]]) -> tuple[float, float, float] | None:
    """Merge in-plane readings of several panels into one 3-D point (axes seen twice are averaged)."""
    sums = [0.0, 0.0, 0.0]
    counts = [0, 0, 0]
    for panel, h, v in parts:
        for axis, value in ((panel["h_axis"], h), (panel["v_axis"], v)):
            i = "xyz".index(axis)
            sums[i] += value
            counts[i] += 1
    if not all(counts):
        return None
    return (sums[0] / counts[0], sums[1] / counts[1], sums[2] / counts[2])


def read_ct(frame: Mapping[str, Any], axis_hint: Sequence[float] = (0.0, 0.0, -1.0)) -> CTReading:
    """Locate the tumour, the incision marker and the needle tip in a CT frame.

    ``axis_hint`` is the needle direction the reader believes (the pen's axis): the tip is the end of
    the bright needle streak furthest along it.
    """
    image = np.asarray(frame["image"])
    tumour: list[tuple[Mapping[str, Any], float, float]] = []
    marker: list[tuple[Mapping[str, Any], float, float]] = []
    tip: list[tuple[Mapping[str, Any], float, float]] = []
    for panel in frame["panels"]:
        c0, size = panel["col0"], panel["size_px"]
        sub = image[:, c0 : c0 + size]
        rows, cols = np.nonzero((sub >= TUMOUR_BAND[0]) & (sub <= TUMOUR_BAND[1]))
        if len(rows):
            tumour.append((panel, *_to_mm(panel, float(cols.mean()), float(rows.mean()))))
        rows, cols = np.nonzero((sub >= MARKER_BAND[0]) & (sub <= MARKER_BAND[1]))
        if len(rows):
            marker.append((panel, *_to_mm(panel, float(cols.mean()), float(rows.mean()))))
        rows, cols = np.nonzero(sub >= NEEDLE_MIN)
        if len(rows):
            ih, iv = "xyz".index(panel["h_axis"]), "xyz".index(panel["v_axis"])
            dh, dv = float(axis_hint[ih]), -float(axis_hint[iv])  # rows grow downwards
            n = math.hypot(dh, dv)
            if n < 0.05:  # the needle points into the slice: its projection is a dot
                c, r = float(cols.mean()), float(rows.mean())
            else:
                proj = cols * (dh / n) + rows * (dv / n)
                far = proj >= proj.max() - 0.75
                c, r = float(cols[far].mean()), float(rows[far].mean())
            tip.append((panel, *_to_mm(panel, c, r)))
    return CTReading(_combine(tumour), _combine(marker), _combine(tip))
