"""What the virtual needle operator senses: where it feels its hand, and the forces on it.

Pure per-trial state, no decisions: :class:`PositionSense` is its sense of where the needle tip is (a
proprioceptive error that drifts with movement, corrected by the last image, and the uncertainty it keeps
about both); :func:`feel_force` splits the force on the hand into the resistance along the needle and the
lateral push; :class:`AxialCueDetector` notices a rise of the axial resistance above what the liver felt
like on the way in (an absolute threshold or a Weber fraction of the running baseline, whichever is
larger). The operator (:mod:`studyctl.participants.needle_operator`) decides what to do with them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

Vec = tuple[float, float, float]


@dataclass(frozen=True)
class Plan:
    """A straight path read from the planning scan: marker (incision) to tumour, and the pre-entry point."""

    tumour: Vec
    marker: Vec
    u: Vec  # unit direction marker → tumour
    length: float  # mm from marker to tumour
    entry: Vec  # where the tip waits above the incision before entering

    def depth(self, b: Vec) -> float:
        """Depth of ``b`` along the path, from the marker (mm)."""
        m, u = self.marker, self.u
        return (b[0] - m[0]) * u[0] + (b[1] - m[1]) * u[1] + (b[2] - m[2]) * u[2]


class PositionSense:
    """Where it believes the tip is: felt hand position + drifting error + the last image's correction.

    ``beta`` is the proprioceptive error (unknown to it), ``corr`` the offset the last image taught it,
    ``sig_lat``/``sig_ax`` its uncertainty (mm) across and along the path.
    """

    __slots__ = ("beta", "corr", "sig_lat", "sig_ax")

    def __init__(self, sigma0_mm: float) -> None:
        self.beta = [0.0, 0.0, 0.0]
        self.corr: Vec = (0.0, 0.0, 0.0)
        self.sig_lat = sigma0_mm
        self.sig_ax = sigma0_mm

    def drift(self, moved_mm: float, drift_per_sqrt_mm: float, z: Sequence[float], *,
              believed_per_sqrt_mm: float = 0.0) -> None:
        """Position sense drifts with intended movement (a random walk in √mm); so does its uncertainty, at the
        rate it believes its sense drifts (``believed_per_sqrt_mm``; 0: its true rate)."""
        if moved_mm <= 0.0:
            return
        s = drift_per_sqrt_mm * math.sqrt(moved_mm)
        b = self.beta
        b[0] += s * z[0]
        b[1] += s * z[1]
        b[2] += s * z[2]
        rate = believed_per_sqrt_mm if believed_per_sqrt_mm > 0.0 else drift_per_sqrt_mm
        grow = rate**2 * moved_mm
        self.sig_lat = math.sqrt(self.sig_lat**2 + grow)
        self.sig_ax = math.sqrt(self.sig_ax**2 + grow)

    def felt(self, percept: Mapping[str, Any], last_cmd: Vec) -> Vec:
        """Where it feels the handle: the true position plus its position-sense error (the last command
        when the device reports no position)."""
        b = self.beta
        if "x_mm" in percept:
            return (percept["x_mm"] + b[0], percept["y_mm"] + b[1], percept["z_mm"] + b[2])
        return (last_cmd[0] + b[0], last_cmd[1] + b[1], last_cmd[2] + b[2])

    def belief(self, percept: Mapping[str, Any], last_cmd: Vec) -> Vec:
        f, c = self.felt(percept, last_cmd), self.corr
        return (f[0] + c[0], f[1] + c[1], f[2] + c[2])

    def see_tip(self, tip: Vec, felt: Vec, resolution_mm: float, *, axis: Vec | None = None,
                keep_lat_mm: float = 0.0) -> Vec:
        """An image shows the true tip: the correction becomes image − felt; returns the previous correction.

        With ``keep_lat_mm`` > 0 (and the needle ``axis``), a change of the correction across the axis smaller
        than that is left alone (an online correction only once the seen error passes a threshold); the part
        along the axis is always taken.
        """
        old = self.corr
        new = (tip[0] - felt[0], tip[1] - felt[1], tip[2] - felt[2])
        if keep_lat_mm > 0.0 and axis is not None:
            d = (new[0] - old[0], new[1] - old[1], new[2] - old[2])
            along = d[0] * axis[0] + d[1] * axis[1] + d[2] * axis[2]
            lat = (d[0] - along * axis[0], d[1] - along * axis[1], d[2] - along * axis[2])
            if math.sqrt(lat[0] ** 2 + lat[1] ** 2 + lat[2] ** 2) < keep_lat_mm:
                new = (old[0] + along * axis[0], old[1] + along * axis[1], old[2] + along * axis[2])
        self.corr = new
        self.sig_lat = self.sig_ax = resolution_mm
        return old


@dataclass(frozen=True)
class FeltForce:
    """The force on the hand as felt along and across the needle axis (N)."""

    axial: float  # resistance along the needle (positive: pushing back)
    radial: Vec  # the lateral part of the force
    radial_n: float  # its magnitude


def feel_force(percept: Mapping[str, Any], axis: Vec, noise_n: float, z: Sequence[float]) -> FeltForce | None:
    """The device's force with perceptual noise (``z[3:6]``), split along ``axis``; None without a force."""
    if "fx_n" not in percept:
        return None
    fx, fy, fz = percept["fx_n"] + noise_n * z[3], percept["fy_n"] + noise_n * z[4], percept["fz_n"] + noise_n * z[5]
    a = axis
    f_ax = -(fx * a[0] + fy * a[1] + fz * a[2])  # resistance felt along the needle
    rx, ry, rz = fx + f_ax * a[0], fy + f_ax * a[1], fz + f_ax * a[2]
    return FeltForce(f_ax, (rx, ry, rz), math.sqrt(rx * rx + ry * ry + rz * rz))


class AxialCueDetector:
    """Notices a rise of the axial resistance above the liver's running baseline while sliding in.

    On the first half of the path it learns what liver resistance feels like (kept for the whole trial);
    deeper, a rise above ``max(threshold, weber·|baseline|)`` held for ``hold_s`` is a cue. The start of a
    push feels stiffer (stiction), so in its first 0.3 s it expects ~30 % more. Once a cue is felt it also keeps
    how clearly: the largest rise since (``peak``) over the rise it needed (``need``), :meth:`clearness`.
    """

    __slots__ = ("baseline", "run_s", "felt", "settle_s", "peak", "need")

    def __init__(self) -> None:
        self.baseline: float | None = None
        self.run_s = 0.0
        self.felt = False
        self.settle_s = 0.0
        self.peak = 0.0
        self.need = 0.0

    def clearness(self) -> float:
        """How far above its own detection need the felt cue rose (peak rise / need; 0 when none was felt)."""
        return self.peak / self.need if self.felt and self.need > 0.0 else 0.0

    def expect_change(self, settle_s: float = 0.5) -> None:
        """It has just sped up on purpose: the resistance it now feels rise is its own doing (it knows its own
        motor command), so for ``settle_s`` the baseline follows the force instead of the rise counting as a cue."""
        self.settle_s = settle_s
        self.run_s = 0.0

    def update(
        self,
        f_ax: float,
        depth: float,
        half_length: float,
        moving_s: float,
        dt: float,
        threshold_n: float,
        weber: float,
        hold_s: float = 0.05,
    ) -> bool:
        """Feed one decision's axial force; True the first time a cue is felt in this trial."""
        steady = moving_s >= 0.5 and f_ax > 0.0  # sliding in, not starting, stopping or pulling
        if self.baseline is None or depth < half_length:
            if steady:
                b0 = self.baseline
                self.baseline = f_ax if b0 is None else b0 + 0.1 * (f_ax - b0)
            self.run_s = 0.0
            return False
        if self.settle_s > 0.0:
            self.settle_s -= dt
            if f_ax > 0.0:
                self.baseline += (dt / 0.1) * (f_ax - self.baseline)
            return False
        rise = f_ax - self.baseline
        need = max(threshold_n, weber * abs(self.baseline))
        if moving_s < 0.3:
            need += 0.3 * abs(self.baseline)
        if self.felt:
            self.peak = max(self.peak, rise)
        if rise > need:
            self.run_s += dt
            if self.run_s >= hold_s and not self.felt:
                self.felt = True
                self.peak, self.need = rise, need
                return True
            return False
        self.run_s = 0.0
        if steady:
            self.baseline += (dt / 0.3) * (f_ax - self.baseline)
        return False
