"""Eq. 2 and its discretisation against scipy.signal's continuous-time responses.

Stated tolerance: the FOH-discretised filter, run on a linearly interpolated input, matches
``scipy.signal.lsim`` of the continuous transfer function (which integrates the same piecewise-linear
input exactly) to 1e-9 of the response's peak, at every model rate used (100 Hz - 10 kHz).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.errors import ModelParameterError
from studyctl.models import capr

TYPES = list(capr.TYPES.values())
RATES = [100.0, 500.0, 1000.0, 10000.0]
TOL = 1e-9


def _dlsim(sys_d, u):
    ad, bd, cd, dd = sys_d
    x = np.zeros(ad.shape[0])
    y = np.empty(len(u))
    for i, ui in enumerate(u):
        y[i] = (cd @ x + dd[:, 0] * ui)[0]
        x = ad @ x + bd[:, 0] * ui
    return y


def _input(rng, fs, seconds=1.0):
    """A force-like piecewise-linear signal: steps, ramps and noise, 0-3 N."""
    n = int(seconds * fs)
    knots = np.sort(rng.uniform(0, seconds, 12))
    vals = rng.uniform(0, 3.0, 12)
    t = np.arange(n) / fs
    u = np.interp(t, knots, vals) + 0.01 * rng.standard_normal(n)
    u[0] = 0.0  # from rest: scipy's FOH state equals the physical state only when the input starts at 0
    return t, u


@pytest.mark.parametrize("aff", TYPES, ids=[t.name for t in TYPES])
def test_state_space_realises_the_transfer_function(aff):
    from scipy import signal
    num, den = capr.transfer_function(aff)
    a, b, c, d = capr.state_space(aff)
    w = 2 * np.pi * np.logspace(-1, 3.5, 60)
    _, h_tf = signal.freqs(num, den, worN=w)
    h_ss = np.array([(c @ np.linalg.solve(1j * wi * np.eye(len(a)) - a, b) + d)[0, 0] for wi in w])
    # relative 1e-8: freqs evaluates the companion-form polynomials (coefficients up to ~1e10 for PC)
    assert np.max(np.abs(h_ss - h_tf) / np.maximum(np.abs(h_tf), 1e-30)) < 1e-8


def test_eq2_by_hand_at_one_frequency():
    """Eq. 2 typed in directly (independent of transfer_function's polynomial algebra)."""
    for aff in TYPES:
        s = 1j * 2 * math.pi * 7.0
        wb = 2 * math.pi * aff.f_b_hz
        bpf = (aff.k_b1 * wb / aff.q * s + aff.k_b2 * s * s) / (s * s + wb / aff.q * s + wb * wb)
        lpf = aff.k_u * 2 * math.pi * aff.f_l_hz / (s + 2 * math.pi * aff.f_l_hz) if aff.k_u else 0.0
        expected = bpf * wb / (s + wb) + lpf
        num, den = capr.transfer_function(aff)
        assert np.polyval(num, s) / np.polyval(den, s) == pytest.approx(expected, rel=1e-12)


def test_static_gains():
    """SA1 holds K_u·F at DC (the BPF has a zero at s = 0); RA1 and PC give nothing for a constant force."""
    for aff in TYPES:
        num, den = capr.transfer_function(aff)
        assert np.polyval(num, 0) / np.polyval(den, 0) == pytest.approx(aff.k_u, abs=1e-15)


@pytest.mark.parametrize("fs", RATES)
@pytest.mark.parametrize("aff", TYPES, ids=[t.name for t in TYPES])
def test_foh_discretisation_matches_lsim(aff, fs):
    from scipy import signal
    rng = np.random.default_rng(int(fs) + len(aff.name))
    t, u = _input(rng, fs, seconds=0.6 if fs > 5000 else 1.5)
    tf = signal.TransferFunction(*capr.transfer_function(aff))
    _, y_ref, _ = signal.lsim(tf, u, t)
    y = _dlsim(capr.discretise(aff, 1.0 / fs), u)
    scale = np.max(np.abs(y_ref))
    assert scale > 0
    assert np.max(np.abs(y - y_ref)) <= TOL * scale


@pytest.mark.parametrize("aff", TYPES, ids=[t.name for t in TYPES])
def test_step_response_matches_scipy_step(aff):
    from scipy import signal
    fs = 2000.0
    t = np.arange(int(0.5 * fs)) / fs
    tf = signal.TransferFunction(*capr.transfer_function(aff))
    _, y_ref = signal.step(tf, T=t)
    u = np.ones_like(t)
    u[0] = 0.0  # FOH: a unit step reached within the first sample, the same input lsim sees below
    _, y_lsim, _ = signal.lsim(tf, u, t)
    y = _dlsim(capr.discretise(aff, 1.0 / fs), u)
    assert np.max(np.abs(y - y_lsim)) <= TOL * np.max(np.abs(y_lsim))
    # after the first sample the step responses agree to the shift of half a sample's ramp
    late = t > 0.05
    assert np.max(np.abs(y[late] - y_ref[late])) <= 0.02 * np.max(np.abs(y_ref))


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 2e-3, 0.02, 0.1])
def test_discretisation_is_stable_at_every_step(dt):
    for aff in TYPES:
        ad, *_ = capr.discretise(aff, dt)
        assert np.max(np.abs(np.linalg.eigvals(ad))) < 1.0


def test_backward_euler_of_the_public_code_is_less_accurate():
    """The CAPR code's implicit finite differences at 500 Hz drift from the continuous response; FOH does not."""
    from scipy import signal
    aff = capr.RA1
    fs = 500.0
    t, u = _input(np.random.default_rng(5), fs)
    _, y_ref, _ = signal.lsim(signal.TransferFunction(*capr.transfer_function(aff)), u, t)
    y_foh = _dlsim(capr.discretise(aff, 1 / fs), u)
    y_be = _dlsim(capr.discretise(aff, 1 / fs, method="backward_diff"), u)
    err_foh = np.max(np.abs(y_foh - y_ref))
    err_be = np.max(np.abs(y_be - y_ref))
    assert err_foh < 1e-6 * err_be


def test_bad_step_is_rejected():
    with pytest.raises(ModelParameterError, match="time step 0 must be > 0 s"):
        capr.discretise(capr.SA1, 0)


def test_lifted_model_equals_sample_by_sample_filtering():
    """CaprModel's block (lifted) update gives the same filter output as the plain recurrence."""
    pop = capr.build_population(capr.SA1)
    model = capr.CaprModel([pop], fs_model=500.0)
    ad, bd, cd, dd = capr.discretise(capr.SA1, model.dt)
    rng = np.random.default_rng(3)
    forces = rng.uniform(0, 1.5, 40)
    u = np.concatenate([[0.0], np.concatenate([np.linspace(a, b, model.m + 1)[1:] for a, b in
                                               zip(np.r_[0.0, forces[:-1]], forces, strict=True)])])
    y_ref = _dlsim((ad, bd, cd, dd), u)[1:]
    got = []
    n = model._n_states
    z = np.zeros(n + 2)
    for f in forces:
        z[-1] = f
        out = model._lin @ z
        got.append(out[: model.m])
        z[:n], z[-2] = out[model.m:], f
    assert np.max(np.abs(np.concatenate(got) - y_ref)) <= 1e-12 * np.max(np.abs(y_ref))
