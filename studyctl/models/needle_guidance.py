"""Where the needle should go and how it is pushed there: the layers' geometry, the needle body frame, and the
radial guidance of Selim, Dresscher & Abayazid (Sensors 2024, 24, 5560).

Radial guidance (eq. 1) is a PD spring-damper in the needle's body frame towards the planned line (incision
point → tumour centroid) with a tolerance capsule of radius ``tolerance_mm``: zero force inside, a spring on
``r − t`` outside, and the damper faded in over ``damping_band_mm`` so that the force is continuous at the
capsule edge; the spring saturates at ``radial_max_n``. Body-frame forces are rotated to the device frame
(eq. 7). :meth:`NeedleTissueModel.step <studyctl.models.needle.NeedleTissueModel.step>` writes the same
arithmetic inline in its 1 kHz loop (a call per tick would cost more than the math); these functions are the
readable statement of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class NeedleGeometry:
    """Where the layers are, in the device frame (mm): nested spheres and the planned straight path.

    The capsule is the surface of the liver sphere; the tumour sphere sits inside it. The planned path
    runs from ``incision_mm`` to the tumour centroid.
    """

    liver_center_mm: tuple[float, float, float]
    liver_radius_mm: float
    tumour_center_mm: tuple[float, float, float]
    tumour_radius_mm: float
    incision_mm: tuple[float, float, float]

    @property
    def planned_direction(self) -> tuple[float, float, float]:
        a, b = self.incision_mm, self.tumour_center_mm
        d = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
        n = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        return (d[0] / n, d[1] / n, d[2] / n)

    @property
    def planned_length_mm(self) -> float:
        return math.dist(self.incision_mm, self.tumour_center_mm)


def body_frame(ux: float, uy: float, uz: float) -> tuple[float, float, float, float, float, float]:
    """Radial axes (y_B, z_B) of the needle body frame whose x_B is the unit needle axis ``u``.

    y_B is horizontal (ẑ × u normalised); near a vertical needle x̂ × u is used instead. Returns
    ``(yx, yy, yz, zx, zy, zz)``; the columns (u, y_B, z_B) form the rotation R_BI of eq. (7).
    """
    # ẑ × u = (−uy, ux, 0)
    yx, yy, yz = -uy, ux, 0.0
    n = math.sqrt(yx * yx + yy * yy)
    if n < 1e-6:  # needle vertical: use x̂ × u = (0, −uz, uy)
        yx, yy, yz = 0.0, -uz, uy
        n = math.sqrt(yy * yy + yz * yz)
    yx, yy, yz = yx / n, yy / n, yz / n
    # z_B = u × y_B
    zx = uy * yz - uz * yy
    zy = uz * yx - ux * yz
    zz = ux * yy - uy * yx
    return yx, yy, yz, zx, zy, zz


def body_to_device(u: tuple[float, float, float], f_body: tuple[float, float, float]) -> tuple[float, float, float]:
    """Eq. (7): rotate (f_axial, f_radial_y, f_radial_z) from the needle body frame to the device frame."""
    ux, uy, uz = u
    yx, yy, yz, zx, zy, zz = body_frame(ux, uy, uz)
    fa, fy, fz = f_body
    return (fa * ux + fy * yx + fz * zx, fa * uy + fy * yy + fz * zy, fa * uz + fy * yz + fz * zz)


def radial_guidance(
    e_y_mm: float,
    e_z_mm: float,
    v_y_mm_s: float,
    v_z_mm_s: float,
    kp: float,
    kd: float,
    tolerance_mm: float,
    damping_band_mm: float,
    max_n: float = math.inf,
) -> tuple[float, float]:
    """Eq. (1) with a tolerance capsule: body-frame radial force (N) for offset ``e`` towards the line.

    ``e`` points from the needle to the planned line (mm); ``v`` is the radial velocity (mm/s). Zero inside
    the capsule (|e| ≤ t); outside, ``kp·(|e| − t)`` (at most ``max_n``) towards the line plus ``kd·v``
    opposing motion, the damper faded in linearly over ``damping_band_mm`` so the force is continuous at
    |e| = t.
    """
    r = math.sqrt(e_y_mm * e_y_mm + e_z_mm * e_z_mm)
    if r <= tolerance_mm:
        return 0.0, 0.0
    f_spring = kp * (r - tolerance_mm) * 1e-3
    if f_spring > max_n:  # saturation keeps the force continuous
        f_spring = max_n
    spring = f_spring / r
    w = (r - tolerance_mm) / damping_band_mm
    if w > 1.0:
        w = 1.0
    damp = w * kd * 1e-3
    return spring * e_y_mm - damp * v_y_mm_s, spring * e_z_mm - damp * v_z_mm_s


__all__ = ["NeedleGeometry", "body_frame", "body_to_device", "radial_guidance"]
