"""Needle–tissue forces and needle guidance for the virtual CT-guided insertion of seed 001.

The model follows Selim, Dresscher & Abayazid (Sensors 2024, 24, 5560), whose axial forces are the
Okamura, Simone & O'Leary (IEEE TBME 2004) decomposition

    f_axial = f_stiffness + f_cutting + f_friction

* **stiffness** (eq. 3) ``k·Δx² + k·Δx`` while the tip pushes an unbroken surface (capsule, tumour),
  ``Δx`` in metres from the first contact; an explicit **puncture event** ends it when the spring force
  reaches the layer's puncture force (latched per track, so it never re-arms while inside).
* **cutting** (eq. 4) ``k_cut·v`` only while the tip advances into tissue that this track has not cut
  yet; retraction and re-advancing along an existing track do not cut.
* **friction** (eq. 5, 6) Karnopp static/dynamic levels plus depth-dependent damping
  ``c·v·(x_penet − x_cur)``; on retraction friction is the only axial force.

Two modelling choices the paper leaves open are made here and named in :class:`NeedleParams`:

1. Table 1 gives the friction levels in newtons, yet Figure 3 settles near 0.3 N in liver tissue, below the
   0.8 N dynamic level. Shaft friction grows with the length of shaft in contact (Okamura et al.), so the
   levels are read as the friction of a fully embedded shaft and scale with ``embedded length /
   friction_ref_length_mm`` (default: the 150 mm needle). With BL parameters at 15 mm/s this gives the
   Figure 3 shape (rise at the capsule, drop at puncture, slow rise to ≈0.3 N at 40 mm depth).
2. Puncture forces are not in Table 1: ``capsule_puncture_n`` = 1.0 N and ``tumour_puncture_n`` = 1.5 N
   (a tumour whose stiffness is 0, as in BL, is punctured at contact).

Karnopp in a haptic loop has no measured hand force, so sticking is rendered with a *stick anchor*: on
entering the stick band (|v| below ``stick_band_mm_s``, sized above the device's velocity noise) the anchor
is placed so that the spring force equals the friction force of the previous tick (no jump at stick onset);
the spring-damper to the anchor is saturated at the static level, and saturation is breakaway. After a
breakaway the friction keeps the breakaway direction until the speed leaves the band, so velocity noise
around zero cannot flip its sign (no chattering).

Radial guidance (eq. 1) and the body frame (eq. 7) are in :mod:`studyctl.models.needle_guidance`. Releasing
the button switches to the maintain mode (eq. 8, same gains, 3-D, towards the pose at release) through a
smoothstep cross-fade of ``maintain_blend_s``. Positions are in mm, velocities in mm/s, gains in SI units as in
Table 1.

The hot path :meth:`NeedleTissueModel.step` works on plain Python floats: at 1 kHz one tick costs a few
microseconds, where small NumPy arrays would cost tens.
"""

from __future__ import annotations

import math

from studyctl.models.needle_guidance import NeedleGeometry, body_frame
from studyctl.models.needle_params import (  # noqa: F401 - the model's parameters, importable from here too
    UNITS,
    NeedleParams,
    local_stiffness_at_puncture,
    min_damping_for_rate,
)


def stiffness_force(k: float, dx_m: float) -> float:
    """Okamura's nonlinear capsule spring, eq. (3): ``k·Δx² + k·Δx`` (N) for Δx ≥ 0 in metres."""
    if dx_m <= 0.0:
        return 0.0
    return k * (dx_m * dx_m + dx_m)


class _Track:
    """One needle track through the liver: where it entered, its axis, how deep it has cut."""

    __slots__ = ("ex", "ey", "ez", "ux", "uy", "uz", "max_s", "capsule_punctured", "tumour_punctured")

    def __init__(self, ex: float, ey: float, ez: float, ux: float, uy: float, uz: float) -> None:
        self.ex, self.ey, self.ez = ex, ey, ez
        self.ux, self.uy, self.uz = ux, uy, uz
        self.max_s = 0.0
        self.capsule_punctured = False
        self.tumour_punctured = False


# Layer codes reported by the model (also the ``layer`` channel of the controller).
OUTSIDE, CAPSULE, LIVER, TUMOUR_SURFACE, TUMOUR = 0, 1, 2, 3, 4
LAYER_NAMES = {
    OUTSIDE: "outside",
    CAPSULE: "capsule",
    LIVER: "liver",
    TUMOUR_SURFACE: "tumour_surface",
    TUMOUR: "tumour",
}

# Karnopp states
_SLIP, _STICK, _BREAKAWAY = 0, 1, 2


class NeedleTissueModel:
    """The stateful 1 kHz force law: needle pose in, device-frame force out.

    Call :meth:`step` once per servo tick with the tip position (mm), its velocity (mm/s), the pen's axis
    (any non-zero vector) and the button (pressed = inserting). After each step the attributes
    ``f_axial``, ``f_radial``, ``depth_mm``, ``layer``, ``stuck``, ``maintain`` and ``axis`` describe the
    tick, and ``events`` collects ``(kind, depth_mm)`` for contact, puncture, track reuse and exit.
    """

    def __init__(self, params: NeedleParams, geometry: NeedleGeometry, *, validate: bool = True) -> None:
        if validate:  # only experiments that demonstrate instability switch this off
            params.validate()
        self.params = params
        self.geometry = geometry
        p = params
        g = geometry
        self._lc = g.liver_center_mm
        self._lr2 = g.liver_radius_mm**2
        self._lr = g.liver_radius_mm
        self._tc = g.tumour_center_mm
        self._tr2 = g.tumour_radius_mm**2
        self._a = g.incision_mm
        self._d = g.planned_direction
        self._dt = 1.0 / p.rate_hz
        # per-mm and per-(mm/s) coefficients so the hot path stays in mm
        self._kcap = p.capsule_k_stiff
        self._ktum = p.tumour_k_stiff
        self._inv_lref = 1.0 / p.friction_ref_length_mm
        self._eps = p.stick_band_mm_s
        self._stick_k_mm = p.stick_k * 1e-3
        self._stick_d_mm = p.stick_d * 1e-3
        self._contact_d_mm = p.contact_d * 1e-3
        self._tol = p.tolerance_mm
        self._band = p.damping_band_mm
        self._liver = (p.liver_f_dynamic, p.liver_f_static, p.liver_c * 1e-6, p.liver_k_cut * 1e-3)
        self._tumour = (p.tumour_f_dynamic, p.tumour_f_static, p.tumour_c * 1e-6, p.tumour_k_cut * 1e-3)
        self._kp_mm = p.radial_kp * 1e-3
        self._kd_mm = p.radial_kd * 1e-3
        self._radial_max = p.radial_max_n
        self._entry_line = p.radial_entry_line == 1.0
        self.set_loop_rate(p.rate_hz)  # the maintain cross-fade's step; a reduced simulated rate rescales it
        self._match_cos = math.cos(math.radians(p.track_match_deg))
        self.events: list[tuple[str, float]] = []
        self.reset()

    def set_loop_rate(self, rate_hz: float) -> None:
        """Steps come ``rate_hz`` times a second (a simulated session below ``params.rate_hz``): the maintain
        cross-fade advances by its share of ``maintain_blend_s`` per step, so it takes the same time. The
        K·T/2 damping rule is checked at ``params.rate_hz``, the rate a device runs the model at."""
        self._blend_rate = min(1.0, (1.0 / rate_hz) / self.params.maintain_blend_s)

    def reset(self) -> None:
        """Forget the tracks, puncture flags, friction and mode state (a fresh trial)."""
        self._tracks: list[_Track] = []
        self._track: _Track | None = None
        self._tumour_contact_s: float | None = None
        self._fric_state = _SLIP
        self._anchor = 0.0
        self._break_dir = 0.0
        self._f_fric = 0.0
        self._w = 0.0  # maintain blend weight 0 (insert) … 1 (maintain)
        self._hold = (0.0, 0.0, 0.0)
        self._pressed = True
        self._axis = (0.0, 0.0, -1.0)
        self._raw_axis = self._axis
        self._frame = body_frame(0.0, 0.0, -1.0)
        self.events.clear()
        self.f_axial = 0.0
        self.f_radial = 0.0
        self.depth_mm = 0.0
        self.layer = OUTSIDE
        self.stuck = 0
        self.maintain = 0.0
        self.punctures = 0

    @property
    def axis(self) -> tuple[float, float, float]:
        """The needle axis used this tick (frozen while the needle is in tissue)."""
        return self._axis

    @property
    def in_tissue(self) -> bool:
        return self._track is not None

    # ------------------------------------------------------------------ tracks
    def _enter(self, px: float, py: float, pz: float, ux: float, uy: float, uz: float) -> None:
        """The tip just crossed the liver surface: find the entry point, reuse a matching track or open one."""
        cx, cy, cz = self._lc
        wx, wy, wz = px - cx, py - cy, pz - cz
        b = wx * ux + wy * uy + wz * uz
        disc = b * b - (wx * wx + wy * wy + wz * wz) + self._lr2
        sigma = b + math.sqrt(disc) if disc > 0.0 else 0.0
        if sigma < 0.0:
            sigma = 0.0
        ex, ey, ez = px - sigma * ux, py - sigma * uy, pz - sigma * uz
        tol2 = self.params.track_match_mm**2
        for tr in self._tracks:
            dx, dy, dz = tr.ex - ex, tr.ey - ey, tr.ez - ez
            if dx * dx + dy * dy + dz * dz <= tol2 and tr.ux * ux + tr.uy * uy + tr.uz * uz >= self._match_cos:
                self._track = tr
                self.events.append(("track_reused", sigma))
                break
        else:
            tr = _Track(ex, ey, ez, ux, uy, uz)
            self._tracks.append(tr)
            self._track = tr
            self.events.append(("capsule_contact", sigma))
        tr = self._track
        self._axis = (tr.ux, tr.uy, tr.uz)
        self._frame = body_frame(tr.ux, tr.uy, tr.uz)
        self._tumour_contact_s = None
        self._fric_state = _SLIP
        self._f_fric = 0.0

    # ------------------------------------------------------------------ the tick
    def step(
        self,
        px: float,
        py: float,
        pz: float,
        vx: float,
        vy: float,
        vz: float,
        ax: float,
        ay: float,
        az: float,
        pressed: bool = True,
    ) -> tuple[float, float, float]:
        """One servo tick: the device-frame force (N) for tip position/velocity and pen axis ``a``."""
        tr = self._track
        if tr is None:
            raw = self._raw_axis
            if ax != raw[0] or ay != raw[1] or az != raw[2]:  # the pen moved: new axis and body frame
                n = math.sqrt(ax * ax + ay * ay + az * az)
                if n > 1e-9:
                    self._raw_axis = (ax, ay, az)
                    self._axis = (ax / n, ay / n, az / n)
                    self._frame = body_frame(*self._axis)
            cx, cy, cz = self._lc
            wx, wy, wz = px - cx, py - cy, pz - cz
            if wx * wx + wy * wy + wz * wz < self._lr2:
                ux, uy, uz = self._axis
                self._enter(px, py, pz, ux, uy, uz)
                tr = self._track
        ux, uy, uz = self._axis
        f_ax = 0.0
        layer = OUTSIDE
        stuck = 0
        s = 0.0
        if tr is not None:
            s = (px - tr.ex) * ux + (py - tr.ey) * uy + (pz - tr.ez) * uz
            if s <= 0.0:
                # retracted out of the liver: the track (and its hole in the capsule) stays for reuse
                self.events.append(("needle_withdrawn", 0.0))
                self._track = tr = None
                self._raw_axis = (math.nan, math.nan, math.nan)  # follow the pen again from the next tick
                self._fric_state = _SLIP
                self._f_fric = 0.0
                s = 0.0
            else:
                f_ax, layer, stuck = self._axial(tr, s, px, py, pz, vx * ux + vy * uy + vz * uz)
                if s > tr.max_s:
                    tr.max_s = s
        # radial guidance towards the planned line (or, with radial_entry_line, in tissue towards the line the
        # needle entered along: through its entry point along its frozen axis), in the body frame
        yx, yy, yz, zx, zy, zz = self._frame
        if tr is not None and self._entry_line:
            a0, a1, a2 = tr.ex, tr.ey, tr.ez
            d0, d1, d2 = ux, uy, uz
        else:
            a0, a1, a2 = self._a
            d0, d1, d2 = self._d
        wx, wy, wz = px - a0, py - a1, pz - a2
        lam = wx * d0 + wy * d1 + wz * d2
        ex, ey, ez = lam * d0 - wx, lam * d1 - wy, lam * d2 - wz  # from the tip to its closest point on the line
        e_y = ex * yx + ey * yy + ez * yz
        e_z = ex * zx + ey * zy + ez * zz
        r = math.sqrt(e_y * e_y + e_z * e_z)
        tol = self._tol
        f_y = f_z = 0.0
        if r > tol:
            f_spring = self._kp_mm * (r - tol)
            if f_spring > self._radial_max:
                f_spring = self._radial_max
            spring = f_spring / r
            w = (r - tol) / self._band
            damp = self._kd_mm * (w if w < 1.0 else 1.0)
            f_y = spring * e_y - damp * (vx * yx + vy * yy + vz * yz)
            f_z = spring * e_z - damp * (vx * zx + vy * zy + vz * zz)
        # eq. (7): body → device frame
        fx = f_ax * ux + f_y * yx + f_z * zx
        fy = f_ax * uy + f_y * yy + f_z * zy
        fz = f_ax * uz + f_y * yz + f_z * zz
        # maintain mode (eq. 8) with a smoothstep cross-fade
        if pressed != self._pressed:
            self._pressed = pressed
            if not pressed:
                self._hold = (px, py, pz)
        w = self._w
        if not pressed:
            if w < 1.0:
                w = min(1.0, w + self._blend_rate)
        elif w > 0.0:
            w = max(0.0, w - self._blend_rate)
        self._w = w
        if w > 0.0:
            h0, h1, h2 = self._hold
            kp, kd = self._kp_mm, self._kd_mm
            mx = -kp * (px - h0) - kd * vx
            my = -kp * (py - h1) - kd * vy
            mz = -kp * (pz - h2) - kd * vz
            ws = w * w * (3.0 - 2.0 * w)
            fx += ws * (mx - fx)
            fy += ws * (my - fy)
            fz += ws * (mz - fz)
        self.f_axial = f_ax
        self.f_radial = math.sqrt(f_y * f_y + f_z * f_z)
        self.depth_mm = s
        self.layer = layer
        self.stuck = stuck
        self.maintain = w
        return fx, fy, fz

    def _axial(self, tr: _Track, s: float, px: float, py: float, pz: float, v: float) -> tuple[float, int, int]:
        """Axial force (N, + along the needle axis) for a tip at depth ``s`` mm moving at ``v`` mm/s."""
        p = self.params
        if not tr.capsule_punctured:
            dx = s * 1e-3
            f_st = self._kcap * (dx * dx + dx)
            if f_st < p.capsule_puncture_n:
                # the capsule deflects: only its spring (and a small contact damper) act on the tip
                return -f_st - self._contact_d_mm * v, CAPSULE, 0
            tr.capsule_punctured = True
            tr.max_s = s  # the tissue up to the tip is cut by the puncture itself
            self.punctures += 1
            self.events.append(("capsule_puncture", s))
            self._fric_state = _SLIP
            self._f_fric = 0.0
        # the tumour chord of the shaft (points tip − σ·u, 0 ≤ σ ≤ s) and whether the tip is inside it
        ux, uy, uz = tr.ux, tr.uy, tr.uz
        cx, cy, cz = self._tc
        wx, wy, wz = px - cx, py - cy, pz - cz
        b = wx * ux + wy * uy + wz * uz
        disc = b * b - (wx * wx + wy * wy + wz * wz) + self._tr2
        chord = 0.0
        tip_in_tumour = False
        if disc > 0.0:
            root = math.sqrt(disc)
            s1, s2 = b - root, b + root
            tip_in_tumour = s1 < 0.0 < s2
            lo = s1 if s1 > 0.0 else 0.0
            hi = s2 if s2 < s else s
            if hi > lo:
                chord = hi - lo
        f_tip = 0.0
        layer = LIVER
        if tip_in_tumour and not tr.tumour_punctured:
            if self._tumour_contact_s is None:
                self._tumour_contact_s = s
                self.events.append(("tumour_contact", s))
            dx = (s - self._tumour_contact_s) * 1e-3
            f_st = self._ktum * (dx * dx + dx) if dx > 0.0 else 0.0
            if f_st < p.tumour_puncture_n and self._ktum > 0.0:
                f_tip = -f_st - self._contact_d_mm * v
                layer = TUMOUR_SURFACE
            else:
                tr.tumour_punctured = True
                tr.max_s = s
                self.punctures += 1
                self.events.append(("tumour_puncture", s))
                layer = TUMOUR
        elif tip_in_tumour:
            layer = TUMOUR
        elif self._tumour_contact_s is not None and not tr.tumour_punctured:
            if s > self._tumour_contact_s:
                # a soft tumour pushed all the way through without reaching its puncture force
                tr.tumour_punctured = True
                self.punctures += 1
                self.events.append(("tumour_puncture", s))
            self._tumour_contact_s = None  # withdrawn from an unbroken tumour: it springs back
        if not tr.tumour_punctured:
            chord = 0.0  # an unbroken tumour is pushed, not cut: its chord of the shaft rubs liver
        liver_len = s - chord
        inv = self._inv_lref
        ld, ls, lc, lk = self._liver
        if chord > 0.0:
            td, ts, tc, tk = self._tumour
            f_dyn = (ld * liver_len + td * chord) * inv
            f_sta = (ls * liver_len + ts * chord) * inv
            c_eff = lc * liver_len + tc * chord  # c · depth(m), per (mm/s) → N
        else:
            f_dyn, f_sta, c_eff = ld * s * inv, ls * s * inv, lc * s
        # cutting: only advancing into tissue this track has not cut
        if layer != TUMOUR_SURFACE and v > 0.0 and s > tr.max_s:
            f_tip -= (self._tumour[3] if layer == TUMOUR else lk) * v
        # Karnopp friction rendered through an anchor (a bristle): the friction force is always
        # −k·(s − anchor). Sliding drags the anchor along at the dynamic level; sticking freezes it, so the
        # force is continuous at stick onset and unloads through zero when the hand reverses, storing no
        # more energy than the hand's own work put into it (a preloaded anchor would pump a limit cycle).
        eps = self._eps
        k = self._stick_k_mm
        state = self._fric_state
        if state == _STICK:
            spring = -k * (s - self._anchor)
            if spring > f_sta or spring < -f_sta:
                state = _BREAKAWAY  # the hand's load exceeded the static level
                self._break_dir = 1.0 if spring < 0.0 else -1.0  # the direction the hand pushes
            else:  # only the load ends sticking: a fast reversal unloads the anchor through zero first
                f = spring - self._stick_d_mm * v
                self._f_fric = f
                return f_tip + f, layer, 1
        if state == _BREAKAWAY:
            # until the speed leaves the band its sign is noise: keep the breakaway direction
            along = v * self._break_dir
            if along > eps:
                state = _SLIP
            elif along >= -eps:
                f = -self._break_dir * f_dyn
                self._anchor = s + f / k
                self._fric_state = state
                self._f_fric = f
                return f_tip + f, layer, 0
            else:  # the hand reversed before sliding got going: stick with the anchor where it is
                f = -k * (s - self._anchor)
                self._fric_state = _STICK
                self._f_fric = f
                return f_tip + f, layer, 1
        if -eps < v < eps and f_sta > 0.0:
            # stick: freeze the anchor where sliding left it (same force as the last tick)
            f = self._f_fric
            if f > f_sta or f < -f_sta:  # slip damping can exceed the static level: hold at the limit
                f = f_sta if f > 0.0 else -f_sta
            self._anchor = s + f / k
            self._fric_state = _STICK
            self._f_fric = f
            return f_tip + f, layer, 1
        f = -(f_dyn + c_eff * (v if v > 0.0 else -v))
        if v < 0.0:
            f = -f
        self._anchor = s + f / k  # dragged along
        self._fric_state = _SLIP
        self._f_fric = f
        return f_tip + f, layer, 0
