"""CAPR afferent types: the fitted parameters of SA1, RA1 and PC units, their transfer function (eq. 2) with its
discretisation, and the firing-rate nonlinearity. The model that runs them is :mod:`studyctl.models.capr`."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from studyctl.errors import ModelParameterError

V_L = 0.015  # V, threshold above rest (E_l = −65 mV, threshold −50 mV); CAPR code Receptors.py
E_L = -0.065  # V, resting potential; CAPR code


# --------------------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------------------

_FIT = "CAPR code Data/fitting_paras.npy @f8d19eb (research/capr.md §1)"


@dataclass(frozen=True)
class AfferentType:
    """Parameters of one afferent type. ``sources`` says where each value comes from."""

    name: str
    f_b_hz: float  # band-pass centre frequency
    q: float  # band-pass quality factor
    f_l_hz: float  # static low-pass cut-off (SA1 only; 0 = no static path)
    k_b1: float  # band-pass gain on the first derivative
    k_b2: float  # band-pass gain on the second derivative
    k_u: float  # static path gain
    c_s: float  # current per metre of indentation
    c_e: float  # edge (height variance) current gain
    c_d: float  # network diagonal parameter (G_ii = 4 / C_d)
    r_c: float  # network output scale
    k_f: float  # membrane rate constant 1/τ (s⁻¹)
    w_neg: float  # gain on the negative lobe after rectification (0 = half-wave)
    max_rate_hz: float  # saturation firing rate (sets V_H)
    n_ds: int  # skin-pixel down-sampling
    density_per_cm2: float
    sources: Mapping[str, str] = field(default_factory=dict, compare=False, hash=False)

    def __post_init__(self) -> None:
        checks = {
            "f_b_hz": self.f_b_hz > 0,
            "q": self.q > 0,
            "f_l_hz": self.f_l_hz >= 0,
            "c_d": self.c_d > 0,
            "r_c": self.r_c > 0,
            "k_f": self.k_f > 0,
            "w_neg": 0 <= self.w_neg <= 10,
            "max_rate_hz": self.max_rate_hz > 0,
            "n_ds": self.n_ds >= 1,
            "density_per_cm2": 0 < self.density_per_cm2 <= 1000,
        }
        for key, ok in checks.items():
            value = getattr(self, key)
            if not (ok and math.isfinite(float(value))):
                raise ModelParameterError(f"CAPR {self.name}: parameter {key} = {value!r} is out of range")
        object.__setattr__(self, "sources", MappingProxyType(dict(self.sources)))

    @property
    def v_h(self) -> float:
        """Saturation voltage: the drive at which the linearised rate reaches ``max_rate_hz``."""
        return self.max_rate_hz * V_L / self.k_f


SA1 = AfferentType(
    "SA1", f_b_hz=43.493, q=0.15653, f_l_hz=51.821, k_b1=1.65894, k_b2=1.3e-16, k_u=0.057185,
    c_s=176.528, c_e=176.511, c_d=0.35310, r_c=17.647, k_f=17.655, w_neg=0.0, max_rate_hz=120.0, n_ds=1,
    density_per_cm2=72.2,
    sources={"filter/network/neuron": _FIT, "w_neg": "CAPR code: SA1 Cp = 0 (half-wave)",
             "max_rate_hz": "CAPR code maxfr", "n_ds": "CAPR code Nds", "density_per_cm2": "CAPR code simset.py"},
)
RA1 = AfferentType(
    "RA1", f_b_hz=124.369, q=0.08377, f_l_hz=0.0, k_b1=0.10295, k_b2=1.4602e-5, k_u=0.0,
    c_s=1869.42, c_e=37.377, c_d=0.74782, r_c=37.389, k_f=37.388, w_neg=0.37379, max_rate_hz=200.0, n_ds=1,
    density_per_cm2=143.5,
    sources={"filter/network/neuron": _FIT, "k_u": "CAPR code forces K_u = 0 for RA1",
             "max_rate_hz": "CAPR code maxfr", "density_per_cm2": "CAPR code simset.py"},
)
PC = AfferentType(
    "PC", f_b_hz=231.539, q=1.0, f_l_hz=0.0, k_b1=0.0, k_b2=0.90609, k_u=0.0,
    c_s=2809.17, c_e=56.156, c_d=0.74782, r_c=56.181, k_f=56.185, w_neg=0.56186, max_rate_hz=300.0, n_ds=2,
    density_per_cm2=24.8,
    sources={"filter/network/neuron": _FIT, "k_b1": "CAPR code forces K_b1 = 0 for PC",
             "c_d": "CAPR code uses RA1's C_d for PC (Receptors.py; PC's own fit 1.12362 is unused)",
             "max_rate_hz": "CAPR code maxfr", "n_ds": "CAPR code Nds", "density_per_cm2": "CAPR code simset.py"},
)
TYPES: Mapping[str, AfferentType] = MappingProxyType({"SA1": SA1, "RA1": RA1, "PC": PC})


def afferent_type(name: str) -> AfferentType:
    """The built-in parameters of ``SA1``, ``RA1`` or ``PC``."""
    try:
        return TYPES[name]
    except KeyError:
        raise ModelParameterError(f"unknown afferent type {name!r}; known: {', '.join(TYPES)}") from None


# --------------------------------------------------------------------------------------------------
# Transfer function (eq. 2) and its discretisation
# --------------------------------------------------------------------------------------------------


def transfer_function(t: AfferentType) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator (descending powers of s) of eq. 2 for type ``t``: firing drive / input."""
    wb = 2 * math.pi * t.f_b_hz
    bp_num = np.array([t.k_b2, t.k_b1 * wb / t.q, 0.0])
    bp_den = np.array([1.0, wb / t.q, wb * wb])
    num = np.polymul(bp_num, [wb])
    den = np.polymul(bp_den, [1.0, wb])
    if t.k_u != 0 and t.f_l_hz > 0:
        wl = 2 * math.pi * t.f_l_hz
        lp_num, lp_den = np.array([t.k_u * wl]), np.array([1.0, wl])
        num = np.polyadd(np.polymul(num, lp_den), np.polymul(lp_num, den))
        den = np.polymul(den, lp_den)
    return num, den


def state_space(t: AfferentType) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A well-scaled state-space realisation (A, B, C, D) of eq. 2.

    States: the band-pass pair (x1 = ω_b·∫x2, x2), the low-pass after it (x3) and, for SA1, the static
    path (x4). All entries are of the order of the pole frequencies, unlike a companion form whose
    coefficients reach ω³ ≈ 1e10 for PC.
    """
    wb = 2 * math.pi * t.f_b_hz
    a1 = wb / t.q
    b1, b2 = t.k_b1 * wb / t.q, t.k_b2
    c1, c2 = -b2 * wb, b1 - b2 * a1  # band-pass output = c1·x1 + c2·x2 + b2·u
    static = t.k_u != 0 and t.f_l_hz > 0
    n = 4 if static else 3
    a = np.zeros((n, n))
    b = np.zeros((n, 1))
    a[0, 1] = wb
    a[1, 0], a[1, 1] = -wb, -a1
    b[1, 0] = 1.0
    a[2, 0], a[2, 1], a[2, 2] = wb * c1, wb * c2, -wb
    b[2, 0] = wb * b2
    c = np.zeros((1, n))
    c[0, 2] = 1.0
    if static:
        wl = 2 * math.pi * t.f_l_hz
        a[3, 3] = -wl
        b[3, 0] = t.k_u * wl
        c[0, 3] = 1.0
    return a, b, c, np.zeros((1, 1))


def discretise(t: AfferentType, dt: float, method: str = "foh"):
    """Discrete (A, B, C, D) of eq. 2 at step ``dt`` (``foh``: exact for linearly interpolated input)."""
    from scipy import signal  # lazy: scipy.signal imports scipy.stats (about a second)
    if not dt > 0:
        raise ModelParameterError(f"CAPR: time step {dt!r} must be > 0 s")
    ad, bd, cd, dd, _ = signal.cont2discrete(state_space(t), dt, method=method)
    return ad, bd, cd, dd


# --------------------------------------------------------------------------------------------------
# Rates
# --------------------------------------------------------------------------------------------------


def firing_rate(drive: np.ndarray, k_f, w_neg, v_h) -> np.ndarray:
    """Rate (Hz) of a unit for network drive ``S`` (V): rectify, saturate, then ``K_f·V_s/V_L``.

    ``k_f``, ``w_neg`` and ``v_h`` broadcast against ``drive`` (scalars or per-unit columns). The rate
    is at most ``K_f·V_H/V_L = max_rate_hz``.
    """
    v = np.minimum(np.maximum(drive, -w_neg * drive), v_h)
    return v * (k_f / V_L)
