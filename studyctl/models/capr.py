"""CAPR: a model of the cutaneous afferent population response (SA1, RA1, PC) to a contact force.

The model behind the bio-inspired controller of seed 000 (Ouyang et al.), re-implemented from the
published description and public code (``ouyangqq/model_tactile_pop_response``, "CAPR code";
``ouyangqq/Bioinspired_Haptic_Feedback_sys`` @59941bb, "BHF code"; facts in ``research/capr.md``):

1. **Skin mechanics and resistance network** (static, linear in the force): a flat disc presses the
   fingertip; each afferent's patch of skin pixels gets an indentation; the current
   ``I = C_s·D + C_e·D·var(patch heights)`` spreads through a resistance network (conductance matrix
   ``G``) to give each unit's input ``U_c = R_c·G⁻¹·I``. For a flat disc this is, per unit,
   ``U_c = k·F + m·max(0, F − F_crit)`` (units under the disc, and all units once the disc is pressed
   deeper than its height), so the whole spatial stage reduces to two gains per unit.
2. **Transfer function** (eq. 2 of the paper): band-pass ``(K_b1·(ω_b/Q)·s + K_b2·s²)/(s² + (ω_b/Q)·s +
   ω_b²)`` followed by the low-pass ``ω_b/(s + ω_b)``, plus (SA1 only) the static path
   ``K_u·ω_l/(s + ω_l)``. It is linear, so every unit of a type sees the same filtered signals scaled by
   its gains: one filter per type and path, not one per afferent (exact, tested).
3. **Rectification, saturation, firing rate**: ``V_g = S`` for ``S ≥ 0`` else ``w·|S|``; ``V_s = min(V_g,
   V_H)`` with ``V_H = maxfr·V_L/K_f``; rate ``K_f·V_s/V_L`` (at most ``maxfr``). This is the rate the
   parameters were fitted with (CAPR code ``Model_fitting.py``: "K_f·V_s/0.015, capped at maxfr") and
   what the BHF code's spiking loop computes in effect: its membrane update reads the *initial* array
   value (rest) on the right-hand side, so the neuron integrates ``V_s·K_f`` without leak up to the
   15 mV threshold. We use the rate directly instead of counting spikes in a 0.2 s window
   (deterministic; no ±1-spike, i.e. ±5 Hz, quantisation).
4. **Population read-out** (BHF code): a unit's rate is its mean over the last ``window_s`` (0.2 s); units
   above ``activation_hz`` (5 Hz) are "activated"; each type's output is the mean rate of its activated
   units (0 if none) — the ``f̄`` of the paper's eqs. 3-4.

**Discretisation.** The sensor arrives at ~50 Hz; between samples the force is interpolated linearly
(as the BHF code does) onto the model rate ``fs_model``. The filters are discretised with a first-order
hold (``scipy.signal.cont2discrete(..., method="foh")``): exact for piecewise-linear input at any rate,
so ``fs_model`` only sets how finely the nonlinear stage samples the response. The discrete system is
run in lifted form (one small matrix product per 50 Hz sample for all types and sub-samples).
"""

from __future__ import annotations

import copy
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from types import MappingProxyType

import numpy as np
import pandas as pd
from scipy import linalg

from studyctl.errors import ModelParameterError, NotSupportedError
from studyctl.models.capr_afferents import (  # noqa: F401 - the model's parts, importable from here too
    E_L,
    PC,
    RA1,
    SA1,
    TYPES,
    V_L,
    AfferentType,
    afferent_type,
    discretise,
    firing_rate,
    state_space,
    transfer_function,
)
from studyctl.models.capr_skin import (  # noqa: F401
    REDUCTIONS,
    Population,
    SkinContact,
    build_population,
    fingertip_outline,
    inside_polygon,
    network_matrix,
    reduce_population,
    unit_grid,
)

# --------------------------------------------------------------------------------------------------
# The population model
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CaprResponse:
    """Per input sample: the mean rate of the activated units of each type (Hz) and how many were active."""

    t: np.ndarray
    force_n: np.ndarray
    rates: Mapping[str, np.ndarray]
    active: Mapping[str, np.ndarray]

    def to_frame(self) -> pd.DataFrame:
        """Columns t, force_n, then rate_<type>_hz and active_<type> for SA1, RA1, PC (0 where not modelled)."""
        cols: dict[str, np.ndarray] = {"t": self.t, "force_n": self.force_n}
        for name in TYPES:
            cols[f"rate_{name}_hz"] = self.rates.get(name, np.zeros_like(self.t))
        for name in TYPES:
            cols[f"active_{name}"] = self.active.get(name, np.zeros_like(self.t))
        return pd.DataFrame(cols, columns=list(cols))


def _lift(ad, bd, cd, dd, m):
    """Lifted matrices of x⁺ = Ad·x + Bd·u, y = Cd·x + Dd·u over a block of ``m`` samples."""
    n, q = bd.shape
    p = cd.shape[0]
    powers = [np.eye(n)]
    for _ in range(m):
        powers.append(ad @ powers[-1])
    obs = np.vstack([cd @ powers[i] for i in range(m)])  # (m·p, n)
    toe = np.zeros((m * p, m * q))
    for i in range(m):
        toe[i * p:(i + 1) * p, i * q:(i + 1) * q] = dd
        for l_ in range(i):
            toe[i * p:(i + 1) * p, l_ * q:(l_ + 1) * q] = cd @ powers[i - 1 - l_] @ bd
    ctrl = np.hstack([powers[m - 1 - l_] @ bd for l_ in range(m)])  # (n, m·q)
    return powers[m], obs, toe, ctrl


class CaprModel:
    """Streaming CAPR population: one 50 Hz force sample in, activated-mean rates of each type out.

    Parameters
    ----------
    populations : sequence of Population
        One per afferent type to simulate (model only what the controller reads: e.g. SA1 alone when
        only the balloon is driven).
    input_rate_hz : float
        Rate of the force samples (the controller rate).
    fs_model : float
        Rate of the nonlinear stage; a multiple of ``input_rate_hz``.
    window_s, activation_hz : float
        Read-out window and activation threshold (BHF code: 0.2 s, 5 Hz).
    compiled : bool or None
        Run :meth:`step` as one compiled call (:mod:`studyctl.models.capr_jit`, the same floats bit for bit):
        None uses it when numba is installed and ``STUDYCTL_JIT`` is not ``0``; False always runs the numpy
        path (the reference); True requires it (ImportError without numba).
    """

    def __init__(
        self,
        populations: Sequence[Population],
        *,
        input_rate_hz: float = 50.0,
        fs_model: float = 500.0,
        window_s: float = 0.2,
        activation_hz: float = 5.0,
        compiled: bool | None = None,
    ) -> None:
        if not populations:
            raise ModelParameterError("CAPR: at least one afferent population is needed")
        ratio = fs_model / input_rate_hz
        if not (input_rate_hz > 0 and fs_model > 0 and abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1):
            raise ModelParameterError(
                f"CAPR: fs_model {fs_model} Hz must be a whole multiple (≥ 1) of the input rate {input_rate_hz} Hz"
            )
        if not 0 < window_s <= 10:
            raise ModelParameterError(f"CAPR: window_s = {window_s} must be in (0, 10] s")
        if not 0 <= activation_hz < 1000:
            raise ModelParameterError(f"CAPR: activation_hz = {activation_hz} must be in [0, 1000) Hz")
        self.populations = tuple(populations)
        self.types = tuple(p.afferent.name for p in self.populations)
        if len(set(self.types)) != len(self.types):
            raise ModelParameterError(f"CAPR: afferent types repeat: {self.types}")
        self.input_rate_hz = float(input_rate_hz)
        self.fs_model = float(fs_model)
        self.m = int(round(ratio))
        self.window_ticks = max(1, int(round(window_s * input_rate_hz)))
        self.activation_hz = float(activation_hz)
        self.dt = 1.0 / fs_model
        self._build()
        self._compiled = compiled
        self._jit = _compiled_tick(self, compiled)
        self.reset()
        if self._jit is not None:
            # numba loads (or compiles) the machine code at the first call, 0.1-2 s: pay it here, not on the first
            # tick of a trial, where a real-time device loop would fault as stalled; then back to rest.
            self.step(0.0)
            self.reset()

    # -- construction --------------------------------------------------------------------------------
    def _build(self) -> None:
        from scipy import signal  # lazy: scipy.signal imports scipy.stats (about a second)
        m = self.m
        n_types = len(self.populations)
        # One continuous system per type; discretised (FOH) once, then lifted over the m sub-samples.
        blocks = [state_space(pop.afferent) for pop in self.populations]
        a_all = linalg.block_diag(*(b[0] for b in blocks))
        c_all = linalg.block_diag(*(b[2] for b in blocks))
        b_all = linalg.block_diag(*(b[1] for b in blocks))  # (states, types): input t drives type t
        ad, bd, cd, dd, _ = signal.cont2discrete((a_all, b_all, c_all, np.zeros((n_types, n_types))), self.dt, "foh")
        am, obs, toe, ctrl = _lift(ad, bd, cd, dd, m)
        n = am.shape[0]
        frac = np.arange(1, m + 1) / m
        toe3 = toe.reshape(m * n_types, m, n_types)
        ctrl3 = ctrl.reshape(n, m, n_types)
        # Force path: every type sees F_prev + (F_new − F_prev)·k/m, so the input block is two numbers.
        lin_toe = toe3.sum(axis=2)
        lin_ctrl = ctrl3.sum(axis=2)
        self._lin = np.block([
            [obs, (lin_toe @ (1 - frac))[:, None], (lin_toe @ frac)[:, None]],
            [am, (lin_ctrl @ (1 - frac))[:, None], (lin_ctrl @ frac)[:, None]],
        ])  # [y (m·T); x⁺ (n)] = _lin @ [x; F_prev; F_new]
        self._n_states = n
        # Deep path (same filters, input max(0, F − F_crit) of each type): a second copy of the states.
        self._deep_sys = (am, obs, toe, ctrl)
        self._frac = frac
        sizes = [p.size for p in self.populations]
        n_units = sum(sizes)
        gk = np.zeros((n_units, n_types))
        gm = np.zeros((n_units, n_types))
        negw, vh, scale = (np.empty((n_units, 1)) for _ in range(3))
        members = np.zeros((n_types, n_units))
        self._slices: dict[str, slice] = {}
        start = 0
        for i, pop in enumerate(self.populations):
            sl = slice(start, start + pop.size)
            gk[sl, i] = pop.gain_contact
            gm[sl, i] = pop.gain_deep
            negw[sl], vh[sl], scale[sl] = -pop.afferent.w_neg, pop.afferent.v_h, pop.afferent.k_f / V_L
            members[i, sl] = pop.weights
            self._slices[pop.afferent.name] = sl
            start += pop.size
        self._gk, self._gm = gk, gm
        self._negw, self._vh = negw, vh
        # The per-unit factors of the nonlinear stage spread over the m sub-samples: an operand of the drive's
        # own (N, m) shape is one flat loop for numpy, where the (N, 1) column broadcast ran N inner loops of m
        # (~2x slower at 539 units x 10). The same products, element by element.
        self._negw_full = np.ascontiguousarray(np.broadcast_to(negw, (n_units, m)))
        self._vh_full = np.ascontiguousarray(np.broadcast_to(vh, (n_units, m)))
        self._scale_mean = scale[:, 0] / m  # K_f/V_L and the 1/m of the sub-sample mean in one factor
        self._members = members
        self.n_units = n_units
        self._crit = np.array([p.force_crit_n for p in self.populations])
        self._crit_min = float(self._crit.min())
        self._ones_m = np.ones(m)
        self._sum_thr = self.activation_hz * self.window_ticks  # window sum above which a unit is active
        self._work_buffers()

    def _work_buffers(self) -> None:
        """The arrays a numpy-path step writes into (kept, not made per tick); every model, clones too, owns its own."""
        n_units, m = self.n_units, self.m
        self._drive = np.empty((n_units, m))
        self._deep_drive = np.empty((n_units, m))
        self._tmp = np.empty((n_units, m))
        self._rate = np.empty(n_units)
        self._active = np.empty(n_units)
        self._masked = np.empty(n_units)

    def clone(self) -> CaprModel:
        """A model at rest with this one's built matrices (shared: stepping only reads them) and its own state and
        work buffers. Building one costs ~0.3 s (the lifted state space of ``_build``), which a controller made
        for every trial would otherwise pay every trial; a clone steps to the same floats as a new build."""
        other = copy.copy(self)
        other._work_buffers()
        other._jit = _compiled_tick(other, self._compiled)  # its own scratch arrays and sums (STUDYCTL_JIT as now)
        other.reset()
        return other

    def reset(self) -> None:
        """Rest: zero filter state, empty window, no previous force."""
        self._z = np.zeros(self._n_states + 2)  # [x; F_prev; F_new]
        self._xd = np.zeros(self._n_states)  # deep-path states
        self._ring = np.zeros((self.window_ticks, self.n_units))
        self._sum = np.zeros(self.n_units)
        self._pos = 0
        self._deep_live = False
        self.last_active: dict[str, float] = {name: 0.0 for name in self.types}

    # -- streaming -----------------------------------------------------------------------------------
    def step(self, force_n: float) -> dict[str, float]:
        """Advance by one input sample; return the activated-mean rate (Hz) of each simulated type."""
        if self._jit is None:
            return self._step_numpy(force_n)
        pos = self._pos
        self._deep_live = self._jit(float(force_n), pos, self._deep_live, self._z, self._xd, self._ring, self._sum,
                                    *self._jit_args)
        self._pos = (pos + 1) % self.window_ticks
        counts, sums = self._jit_sums.tolist()
        return self._rates(counts, sums)

    def _step_numpy(self, force_n: float) -> dict[str, float]:
        """:meth:`step` in numpy: the reference the compiled tick reproduces bit for bit."""
        z = self._z
        f_new = float(force_n)
        f_prev = z[-2]
        z[-1] = f_new
        out = self._lin @ z
        n_y = self.m * len(self.types)
        z[:-2] = out[n_y:]
        z[-2] = f_new
        drive = np.matmul(self._gk, out[:n_y].reshape(self.m, -1).T, out=self._drive)  # (N, m)
        deep = max(f_prev, f_new) > self._crit_min
        if deep or self._deep_live:
            am, obs, toe, ctrl = self._deep_sys
            u = f_prev + (f_new - f_prev) * self._frac
            u2 = np.maximum(u[:, None] - self._crit[None, :], 0.0).ravel()  # (sub-sample, type)
            yd = obs @ self._xd + toe @ u2
            self._xd = am @ self._xd + ctrl @ u2
            drive += np.matmul(self._gm, yd.reshape(self.m, -1).T, out=self._deep_drive)
            # The deep paths ring down after the force drops below F_crit; once their state is below
            # 1e-12 (drives < 1e-9 V against a 15 mV threshold) it is set to exactly zero and skipped.
            self._deep_live = deep or bool(np.abs(self._xd).max() > 1e-12)
            if not self._deep_live:
                self._xd[:] = 0.0
        rate = self._tick_rate(drive)
        pos = self._pos
        ring = self._ring[pos]
        self._sum += rate
        self._sum -= ring
        ring[:] = rate
        self._pos = (pos + 1) % self.window_ticks
        return self._readout()

    def _tick_rate(self, drive: np.ndarray) -> np.ndarray:
        """Mean rate (Hz) of each unit over the tick's sub-samples (rectify, saturate, K_f·V/V_L)."""
        v = np.multiply(drive, self._negw_full, out=self._tmp)
        np.maximum(drive, v, out=v)
        np.minimum(v, self._vh_full, out=v)
        rate = np.dot(v, self._ones_m, out=self._rate)
        rate *= self._scale_mean
        return rate

    def _readout(self) -> dict[str, float]:
        # the activation mask as 1.0/0.0 in a kept buffer: the same float operands the bool mask was cast to
        # (no temporary per tick), and the same two matrix-vector products
        active = np.greater(self._sum, self._sum_thr, out=self._active)
        counts = (self._members @ active).tolist()
        sums = (self._members @ np.multiply(self._sum, active, out=self._masked)).tolist()
        return self._rates(counts, sums)

    def _rates(self, counts: list[float], sums: list[float]) -> dict[str, float]:
        """Each type's activated-mean rate from its count of active units and their window sums."""
        out: dict[str, float] = {}
        w = self.window_ticks
        last = self.last_active
        for name, c, total in zip(self.types, counts, sums, strict=True):
            last[name] = c
            out[name] = total / (c * w) if c > 0 else 0.0
        return out

    # -- batch ---------------------------------------------------------------------------------------
    def run(self, force_n: np.ndarray) -> CaprResponse:
        """Whole force sequence (at ``input_rate_hz``) from rest; identical to calling :meth:`step` per sample."""
        f = _force_sequence(force_n)
        self.reset()
        rates = {name: np.empty(f.size) for name in self.types}
        active = {name: np.empty(f.size) for name in self.types}
        for i, value in enumerate(f):
            out = self.step(value)
            for name in self.types:
                rates[name][i] = out[name]
                active[name][i] = self.last_active[name]
        t = np.arange(1, f.size + 1) / self.input_rate_hz
        return CaprResponse(t, f, MappingProxyType(rates), MappingProxyType(active))

    def run_batch(self, force_n: np.ndarray, chunk_ticks: int = 32) -> CaprResponse:
        """The same as :meth:`run`, vectorised over time for a recorded sequence (offline replay).

        The filters run as second-order sections (``scipy.signal.sosfilt``) of each type's FOH-discretised
        system on the whole interpolated input; the nonlinear stage runs over chunks of ticks; windows are
        differences of cumulative sums. Equal to streaming to ~1e-6 relative (float32 nonlinear stage; tested).
        Leaves the streaming state reset.
        """
        from scipy import signal  # lazy: scipy.signal imports scipy.stats (about a second)
        f = _force_sequence(force_n)
        self.reset()
        m, k_ticks, n_types = self.m, f.size, len(self.types)
        prev = np.concatenate([[0.0], f[:-1]])
        u = (prev[:, None] + (f - prev)[:, None] * self._frac[None, :]).ravel()  # sub-samples 1..K·m
        u = np.concatenate([[0.0], u])  # the sample at t = 0 (rest) that the recurrence starts from
        y_force = np.empty((n_types, u.size - 1))
        y_deep = np.zeros((n_types, u.size - 1))
        deep_any = False
        for i, sos in enumerate(self._sos):
            y_force[i] = signal.sosfilt(sos, u)[1:]
            u2 = np.maximum(u - self._crit[i], 0.0)
            if u2.any():
                deep_any = True
                y_deep[i] = signal.sosfilt(sos, u2)[1:]
        # The nonlinear stage in float32 (3x faster here; rates agree with streaming to ~1e-6 relative),
        # sums accumulated in float64.
        f32 = np.float32
        gk, gm = self._gk.astype(f32), self._gm.astype(f32)
        negw, vh = self._negw.astype(f32), self._vh.astype(f32)
        yf, yd = y_force.astype(f32), y_deep.astype(f32)
        tick_rates = np.empty((self.n_units, k_ticks))
        for a in range(0, k_ticks, chunk_ticks):
            b = min(a + chunk_ticks, k_ticks)
            drive = gk @ yf[:, a * m:b * m]
            if deep_any:
                drive += gm @ yd[:, a * m:b * m]
            v = np.maximum(drive, negw * drive)
            np.minimum(v, vh, out=v)
            tick_rates[:, a:b] = v.reshape(self.n_units, b - a, m).sum(axis=2, dtype=np.float64)
        tick_rates *= self._scale_mean[:, None]
        csum = np.cumsum(tick_rates, axis=1)
        w = self.window_ticks
        window_sum = csum.copy()
        window_sum[:, w:] -= csum[:, :-w]
        act = window_sum > self._sum_thr
        counts = self._members @ act
        sums = self._members @ (window_sum * act)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(counts > 0, sums / (counts * w), 0.0)
        t = np.arange(1, k_ticks + 1) / self.input_rate_hz
        rates = {name: mean[i] for i, name in enumerate(self.types)}
        active = {name: counts[i] for i, name in enumerate(self.types)}
        return CaprResponse(t, f, MappingProxyType(rates), MappingProxyType(active))

    @cached_property
    def _sos(self) -> list[np.ndarray]:
        """Second-order sections of each type's discrete filter (FOH at ``fs_model``), built on first use."""
        from scipy import signal  # lazy: scipy.signal imports scipy.stats (about a second)
        return [signal.zpk2sos(*signal.ss2zpk(*discretise(pop.afferent, self.dt))) for pop in self.populations]


def _compiled_tick(model: CaprModel, compiled: bool | None):
    """The compiled tick for this model with its fixed arguments stored on it, or None for the numpy path.

    It is used only where it provably computes what the numpy path does: every summing matrix-vector product
    has a matrix of two rows or more (numpy calls a dot product, not gemv, for one row) and each unit has one
    type's gain (the gain products then have one non-zero term)."""
    if compiled is False or (compiled is None and os.environ.get("STUDYCTL_JIT", "1") == "0"):
        return None
    try:
        from studyctl.models import capr_jit
    except (ImportError, NotSupportedError):  # no numba (the `fast` extra), or numpy without its bundled OpenBLAS
        if compiled:
            raise
        return None
    am, obs, toe, ctrl = model._deep_sys
    n_types, n_y, n_x = len(model.types), model.m * len(model.types), model._n_states
    one_type = all(int(np.count_nonzero(g, axis=1).max()) <= 1 for g in (model._gk, model._gm))
    if min(model._lin.shape[0], n_y, n_x, model.n_units, n_types) < 2 or not one_type:
        if compiled:
            raise ModelParameterError(f"CAPR: no compiled tick for {n_types} type(s) x {model.m} sub-samples "
                                      "(it needs two rows in every matrix and one type per unit)")
        return None
    c = np.ascontiguousarray
    model._jit_sums = np.empty((2, n_types))  # per type: the count of active units, their window sums
    unit_type = np.concatenate([np.full(p.size, i) for i, p in enumerate(model.populations)])
    units = np.arange(model.n_units)
    model._jit_args = (
        c(model._lin), c(model._gk), c(model._gm), unit_type, model._gk[units, unit_type],
        model._gm[units, unit_type], c(am), c(obs), c(toe), c(ctrl), c(model._frac), c(model._crit), model._crit_min,
        float(model._sum_thr), c(model._members), model._ones_m, c(model._negw[:, 0]), c(model._vh[:, 0]),
        c(model._scale_mean), np.empty(n_y + n_x), np.empty((3, n_y)), np.empty((2, n_x)),
        np.empty((2 * n_types, model.m)), np.empty((model.n_units, model.m)), np.empty((3, model.n_units)),
        model._jit_sums,
    )
    return capr_jit.tick


def _force_sequence(force_n: np.ndarray) -> np.ndarray:
    f = np.asarray(force_n, dtype=float)
    if f.ndim != 1 or not np.all(np.isfinite(f)):
        raise ModelParameterError("CAPR: force sequence must be a 1-D array of finite numbers")
    return f
