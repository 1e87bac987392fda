"""Shared helpers of the needle tests."""

from __future__ import annotations

import functools

import numpy as np


def insert_at_constant_speed(model, geometry, speed_mm_s=15.0, start_mm=-10.0, end_mm=None, dt=1e-3):
    """Drive the tip along the planned path at a constant speed; return arrays of depth and axial force."""
    a = np.array(geometry.incision_mm)
    u = np.array(geometry.planned_direction)
    end = geometry.planned_length_mm + 1.0 if end_mm is None else end_mm
    s = start_mm
    depth, f_axial, layer, s_track = [], [], [], []
    while s <= end:
        p = a + s * u
        v = speed_mm_s * u
        model.step(*p, *v, *u, True)
        depth.append(model.depth_mm)
        f_axial.append(model.f_axial)
        layer.append(model.layer)
        s_track.append(s)
        s += speed_mm_s * dt
    return np.array(s_track), np.array(depth), np.array(f_axial), np.array(layer)


@functools.cache
def _shipped_protocol():
    from studyctl.protocol import load_protocol, resolve_protocol

    return load_protocol(resolve_protocol("needle_insertion"))


def condition_params(condition: str) -> dict:
    """The controller params of one scenario as the shipped protocol writes them (the one place Table 1 is)."""
    return dict(_shipped_protocol().condition(condition).params)


def table1(condition: str) -> dict:
    """The same scenario's parameters under the model's flat names (``liver_k_cut``, ``radial_kp`` …)."""
    from studyctl.controllers.needle import flat_params

    return flat_params(condition_params(condition))
