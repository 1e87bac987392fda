"""The compiled CAPR tick (studyctl.models.capr_jit) gives the numpy path's floats bit for bit, and the numpy path
runs wherever the compiled one is absent, not proven equal, or turned off."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

import numpy as np
import pytest

import studyctl.models
from studyctl.errors import ModelParameterError
from studyctl.models import capr

# the `fast` extra (the `test` extra installs it), asked for without importing numba: its import (~0.25 s CPU) would
# be paid by every collection of the suite, and the tests import it when they run
pytestmark = pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="numba is not installed (the `fast` "
                                "extra)")


@pytest.fixture(scope="module")
def full():
    contact = capr.SkinContact(radius_mm=4.0)  # the bio-inspired controller's contact
    return [capr.build_population(t, contact) for t in capr.TYPES.values()]


def _presses(seed: int, ticks: int) -> np.ndarray:
    """A 50 Hz force trace like a palpator's: presses to 0.3-6 N (past F_crit ≈ 2.1 N, so the deep path starts
    and rings down), holds, releases to a light touch, and sensor noise."""
    rng = np.random.default_rng(seed)
    f = []
    while len(f) < ticks:
        peak, rise, hold, rest = rng.uniform(0.3, 6.0), rng.integers(3, 40), rng.integers(0, 60), rng.integers(1, 80)
        f += list(np.linspace(0.02, peak, rise)) + [peak] * hold + list(np.linspace(peak, 0.02, rise)) + [0.02] * rest
    return np.asarray(f[:ticks]) + rng.normal(0.0, 0.01, ticks)


def _state(model: capr.CaprModel) -> tuple:
    return model._z, model._xd, model._ring, model._sum, model._pos, model._deep_live


def _assert_same(pops, forces, **kwargs) -> capr.CaprModel:
    """Every output and count of the compiled model equals the numpy model's, tick by tick; the states at the end."""
    fast = capr.CaprModel(pops, compiled=True, **kwargs)
    ref = capr.CaprModel(pops, compiled=False, **kwargs)
    assert fast._jit is not None and ref._jit is None
    for i, f in enumerate(forces):
        got, want = fast.step(f), ref.step(f)
        # repr: NaN equal to NaN, and every digit of every rate
        assert repr((got, fast.last_active)) == repr((want, ref.last_active)), f"tick {i}, force {f}"
    for a, b in zip(_state(fast), _state(ref), strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    return fast


def test_compiled_tick_equals_numpy_bit_for_bit(full):
    """Three types (the seed-000 controller), 4,000 ticks of presses; reset in the middle."""
    forces = _presses(0, 4000)
    fast = _assert_same(full, forces)
    assert fast._deep_live in (True, False)
    fast.reset()
    ref = capr.CaprModel(full, compiled=False)
    for f in forces[:500]:
        assert repr(fast.step(f)) == repr(ref.step(f))


@pytest.mark.parametrize("reduction, kwargs", [("clusters", {"clusters": 32}), ("density", {"factor": 2}),
                                               ("contact", {})])
def test_compiled_tick_equals_numpy_for_reduced_populations_and_other_rates(full, reduction, kwargs):
    pops = [capr.reduce_population(p, reduction, **kwargs) for p in full]
    _assert_same(pops, _presses(1, 1500))
    _assert_same(full[1:], _presses(2, 1500), fs_model=1000.0, window_s=0.1, activation_hz=0.0)


def test_non_finite_filter_outputs_take_the_whole_sum(full):
    """A force that overflows the filters: 0·inf is NaN in the BLAS product, and in the compiled tick too."""
    with np.errstate(all="ignore"):
        _assert_same(full, np.array([0.5, 1e308, -1e308, 1e308, 3.0, 1.0, 0.0]))


def test_numpy_path_where_the_compiled_tick_is_not_proven_or_is_off(full, monkeypatch):
    # one type: numpy takes a dot product, not gemv, for the one-row member matrix
    assert capr.CaprModel(full[:1])._jit is None
    with pytest.raises(ModelParameterError, match="no compiled tick for 1 type"):
        capr.CaprModel(full[:1], compiled=True)
    assert capr.CaprModel(full)._jit is not None
    monkeypatch.setenv("STUDYCTL_JIT", "0")
    assert capr.CaprModel(full)._jit is None


def test_numpy_path_without_numba(full, monkeypatch):
    """An install without the `fast` extra: importing the compiled tick fails and the model runs numpy."""
    monkeypatch.delitem(sys.modules, "studyctl.models.capr_jit", raising=False)
    monkeypatch.delattr(studyctl.models, "capr_jit", raising=False)  # `from studyctl.models import` looks here first
    monkeypatch.setitem(sys.modules, "numba", None)  # import numba raises ImportError
    model = capr.CaprModel(full)
    assert model._jit is None
    assert model.step(3.0) == capr.CaprModel(full, compiled=False).step(3.0)
    with pytest.raises(ImportError):
        capr.CaprModel(full, compiled=True)


@pytest.mark.slow  # a fresh process that imports numba and compiles or loads the tick: 2-5 s
def test_compiled_without_anywhere_to_cache_compiles_in_the_process():
    """A read-only install and home: numba has no cache locator (made so here through numba's own
    NUMBA_CACHE_LOCATOR_CLASSES, in a fresh process); the tick still compiles and still equals numpy."""
    script = (
        "import numpy as np\n"
        "from studyctl.models import capr\n"
        "pops = [capr.build_population(t, capr.SkinContact(radius_mm=4.0)) for t in capr.TYPES.values()]\n"
        "fast, ref = capr.CaprModel(pops, compiled=True), capr.CaprModel(pops, compiled=False)\n"
        "forces = np.r_[np.linspace(0.02, 4.0, 30), [4.0] * 20, np.linspace(4.0, 0.02, 30)]\n"
        "print(all(repr(fast.step(f)) == repr(ref.step(f)) for f in forces))\n"
    )
    env = {**os.environ, "NUMBA_CACHE_LOCATOR_CLASSES": "IPythonCacheLocator"}  # None outside IPython
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "True"


@pytest.mark.slow  # a fresh process that imports numba and compiles or loads the tick: 2-5 s
def test_the_machine_code_is_loaded_when_the_model_is_built_not_on_its_first_tick():
    """numba loads or compiles at a function's first call (0.1-2 s); on a trial's first tick that stalled the
    real-time loop of a rehearsal on the driver-board emulator (device_fault loop_stalled). Fresh process."""
    script = (
        "from studyctl.models import capr, capr_jit\n"
        "pops = [capr.build_population(t, capr.SkinContact(radius_mm=4.0)) for t in capr.TYPES.values()]\n"
        "model = capr.CaprModel(pops, compiled=True)\n"
        "print(len(capr_jit.tick.signatures), model._pos, model._deep_live, float(abs(model._z).max()))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["1", "0", "False", "0.0"]  # compiled, and the model still at rest
