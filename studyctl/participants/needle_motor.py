"""How the virtual needle operator moves: the reference it follows and the hand set-point it sends.

Functions of the trial state (:class:`~studyctl.participants.needle_trial.TrialState`) and the person's
params: a free-space reach (minimum jerk) or an advance along a line sets ``st.move``; each decision
:func:`command` advances the reference with the person's speed fluctuation and lateral wobble and turns the
wanted (believed) tip into the hand set-point; :func:`make_action` packs it for the device.
"""

from __future__ import annotations

import math

from studyctl.participants.needle_params import OperatorParams, Vec
from studyctl.participants.needle_trial import Line, MinJerk, TrialState, norm
from studyctl.plugins.interfaces import Action, Request

__all__ = ["command", "make_action", "start_line", "start_reach"]


def start_reach(st: TrialState, start: Vec, goal: Vec, speed: float, *, then: Vec | None = None) -> None:
    """A free-space reach: minimum-jerk reference from ``start`` to ``goal``."""
    st.move = MinJerk(start, goal, max(math.dist(start, goal) / speed, 0.3), then)


def start_line(st: TrialState, start: Vec, direction: Vec, origin: Vec, stop: float, v: float,
               aim: Vec | None = None) -> None:
    """Advance the reference until the believed tip is ``stop`` mm past ``origin`` along ``direction``."""
    b = start
    lead_done = (
        (b[0] - origin[0]) * direction[0] + (b[1] - origin[1]) * direction[1] + (b[2] - origin[2]) * direction[2]
    )
    st.move = Line(direction, direction, aim, origin, stop, v, stop + 5.0, lead_done)


def make_action(st: TrialState, cmd: Vec, requests: tuple[Request, ...]) -> Action:
    a = st.axis
    # Plain Python floats (the same doubles): numpy scalars here would make the device's pen axis, and from
    # it every tick of the controller's force law, numpy-scalar arithmetic, several times slower.
    return Action(
        {
            "x_mm": float(cmd[0]),
            "y_mm": float(cmd[1]),
            "z_mm": float(cmd[2]),
            "dir_x": float(a[0]),
            "dir_y": float(a[1]),
            "dir_z": float(a[2]),
            "button": float(st.button),
        },
        requests,
    )


def command(st: TrialState, p: OperatorParams) -> Vec:
    """Advance the reference, then turn the wanted (believed) tip into a hand set-point."""
    mv = st.move
    dt = st.dt
    z = st.noise()
    if mv is not None and st.button >= 0.5:
        if isinstance(mv, MinJerk):
            mv.elapsed += dt
            s = min(1.0, mv.elapsed / mv.T)
            w = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)
            a, b = mv.a, mv.b
            st.ref = (a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]), a[2] + w * (b[2] - a[2]))
        else:
            # constant speed with a slow fluctuation (signal-dependent motor noise)
            k = dt / 0.5
            st.speed_dev += -k * st.speed_dev + p.speed_noise * math.sqrt(2 * k) * z[6]
            step = mv.v * max(0.2, 1.0 + st.speed_dev) * dt
            r = st.ref
            aim = mv.aim
            if aim is not None:
                d = (aim[0] - r[0], aim[1] - r[1], aim[2] - r[2])
                n = norm(d)
                if n > 2.0:  # close to the aim point the direction is kept
                    mv.dir = (d[0] / n, d[1] / n, d[2] / n)
            u = mv.dir
            st.ref = (r[0] + step * u[0], r[1] + step * u[1], r[2] + step * u[2])
            mv.ref_s += step
    # lateral wobble (Ornstein–Uhlenbeck), stronger with a noisier hand and, advancing faster than its own
    # insertion pace, in proportion to the speed (signal-dependent motor noise, Harris & Wolpert 1998)
    k = dt / p.motor_tau_s
    sd = p.motor_noise_mm * math.sqrt(2 * k)
    if isinstance(mv, Line) and st.button >= 0.5 and mv.v > st.v_ins:
        sd *= mv.v / st.v_ins
    wb = st.wobble
    for i in range(3):
        wb[i] += -k * wb[i] + sd * z[i]
    # wanted believed tip → set-point: undo the (unknown to it) position-sense error and correction
    r, b, c = st.ref, st.sense.beta, st.sense.corr
    cmd = (r[0] - c[0] - b[0] + wb[0], r[1] - c[1] - b[1] + wb[1], r[2] - c[2] - b[2] + wb[2])
    st.last_cmd = cmd
    return cmd
