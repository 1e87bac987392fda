"""One CAPR tick compiled with numba: :meth:`studyctl.models.capr.CaprModel.step`'s numpy path, bit for bit.

Why: at seed 000 the numpy tick cost ~40 µs, nearly all of it the overhead of some twenty small numpy calls
(the arithmetic is ~5,000 multiply-adds). Compiled, the same operations run in one call.

How it stays bit-identical to the numpy path (tested on recorded session forces, element for element):

- Element-wise steps are loops doing the same IEEE operation per element as the numpy ufunc (products, sums,
  ``maximum``/``minimum``, comparisons); no fastmath, so nothing is reassociated or fused.
- Every matrix-vector product that *sums* (``_lin @ z``, the deep path's four products, the sub-sample mean
  ``v @ 1``, the per-type sums ``members @ x``) calls the very routine numpy calls: ``cblas_dgemv`` of numpy's
  own bundled OpenBLAS, with the arguments numpy's matmul passes for a C-contiguous matrix (column-major,
  transposed). Its summation order is the BLAS kernel's, so it is taken from the same library, not re-written.
  numpy calls a dot product, not gemv, for a one-row matrix; :func:`studyctl.models.capr.CaprModel` uses this
  tick only when every such matrix has two rows or more.
- The two gain products ``gk @ y`` and ``gm @ y`` (a unit's gain times its own type's filter output) have one
  non-zero term per unit (a unit belongs to one type; checked when the model is built), so any order of the
  BLAS sum gives that one product exactly; the loop adds the zero terms too, in type order from 0.0.

Importing this module needs numba (ImportError without it) and numpy's bundled ``scipy_openblas64`` (numpy >= 2
wheels; NotSupportedError without it); the model then runs the numpy path.
"""

from __future__ import annotations

import glob
import os

import numpy as np
from llvmlite import binding as _llvm
from numba import njit, types

from studyctl.errors import NotSupportedError

_SYMBOL = "scipy_cblas_dgemv64_"  # numpy >= 2 wheels: scipy-openblas64 (64-bit integers), prefix scipy_, suffix 64_


def _numpy_blas() -> str:
    """Path of the OpenBLAS numpy itself calls, with the cblas_dgemv symbol this module links to."""
    import ctypes

    libs = sorted(glob.glob(os.path.join(os.path.dirname(np.__file__), os.pardir, "numpy.libs",
                                         "libscipy_openblas64_*.so")))
    for path in libs:
        if hasattr(ctypes.CDLL(path), _SYMBOL):
            return path
    raise NotSupportedError(f"the compiled CAPR tick needs numpy's bundled scipy_openblas64 ({_SYMBOL}); "
                      f"numpy {np.__version__} has none")


# Make numpy's BLAS symbols visible to the compiled code: it links to the routine by name, so a cached
# compilation loads in a new process (a pointer baked in would not survive a restart).
_llvm.load_library_permanently(_numpy_blas())
_F8P = types.CPointer(types.float64)
_dgemv = types.ExternalFunction(_SYMBOL, types.void(
    types.int32, types.int32, types.int64, types.int64, types.float64, _F8P, types.int64, _F8P, types.int64,
    types.float64, _F8P, types.int64))
_COL_MAJOR, _TRANS = 102, 112  # CblasColMajor, CblasTrans


def _compiled(fn):
    """``njit`` with numba's on-disk cache where numba has somewhere to write it; else compiled in each process.

    Why: numba refuses ``cache=True`` (RuntimeError at import) when neither the package's folder nor the user's
    home is writable — a read-only install, a locked-down Dask worker. That must cost only the compile time
    (~1.8 s per process), not the simulation.
    """
    try:
        return njit(cache=True)(fn)
    except RuntimeError as err:
        if "no locator available" not in str(err):
            raise
        return njit(fn)


@_compiled
def _mv(a, x, y):  # pragma: no cover - compiled
    """y = a @ x for C-contiguous a, as numpy's matmul calls it: cblas_dgemv(ColMajor, Trans, n, m, 1, a, n, x, 1,
    0, y, 1)."""
    rows, cols = a.shape
    _dgemv(np.int32(_COL_MAJOR), np.int32(_TRANS), cols, rows, 1.0, a.ctypes, cols, x.ctypes, 1, 0.0, y.ctypes, 1)


@_compiled
def _by_type(y, n_types, y_t):  # pragma: no cover - compiled
    """y_t[t, k] = y[k·T + t]: the filter outputs of each type over the sub-samples (``y.reshape(m, T).T``)."""
    for t in range(n_types):
        for k in range(y_t.shape[1]):
            y_t[t, k] = y[k * n_types + t]


@_compiled
def tick(f_new, pos, deep_live, z, xd, ring, total, lin, gk, gm, unit_type, gk_own, gm_own, am, obs, toe, ctrl, frac,
         crit, crit_min, thr, members, ones_m, negw, vh, scale_mean, out, ys, xs, y_t, v, units,
         sums):  # pragma: no cover
    """One tick in place (filter states, ring, window sums; per type the count of active units and their sums in
    ``sums``); returns the deep paths' liveness. The numpy path's statements are quoted beside their loops.
    Scratch: ``ys`` rows yd, toe @ u2, u2; ``xs`` rows am @ xd, ctrl @ u2; ``y_t`` rows force then deep outputs
    by type; ``units`` rows rate, active, masked."""
    n_types = crit.shape[0]
    m = frac.shape[0]
    n_y = m * n_types
    n_x = out.shape[0] - n_y
    n_units = v.shape[0]
    f_prev = z[n_x]
    z[n_x + 1] = f_new
    _mv(lin, z, out)  # out = self._lin @ z
    for i in range(n_x):
        z[i] = out[n_y + i]
    z[n_x] = f_new
    _by_type(out, n_types, y_t[:n_types])
    deep = (f_new if f_new > f_prev else f_prev) > crit_min  # max(f_prev, f_new) > crit_min, Python's max
    live = deep or deep_live
    if live:
        yd, toe_u2, u2 = ys[0], ys[1], ys[2]
        d = f_new - f_prev
        for k in range(m):
            u = f_prev + d * frac[k]
            for t in range(n_types):
                w = u - crit[t]
                u2[k * n_types + t] = w if (w >= 0.0) | (w != w) else 0.0  # np.maximum(u - crit, 0.0)
        _mv(obs, xd, yd)  # yd = obs @ xd + toe @ u2
        _mv(toe, u2, toe_u2)
        for i in range(n_y):
            yd[i] = yd[i] + toe_u2[i]
        _mv(am, xd, xs[0])  # self._xd = am @ self._xd + ctrl @ u2
        _mv(ctrl, u2, xs[1])
        big = 0.0
        for i in range(n_x):
            xd[i] = xs[0, i] + xs[1, i]
            a = abs(xd[i])
            if (a > big) | (a != a):  # np.abs(xd).max(): NaN wins
                big = a
        _by_type(yd, n_types, y_t[n_types:])
        deep_live = deep or big > 1e-12
        if not deep_live:
            xd[:] = 0.0
    # drive = gk @ y_force (+ gm @ y_deep), then _tick_rate's v = minimum(maximum(drive, drive·negw), vh).
    # The BLAS product sums a unit's row over the types from 0.0; only its own type's gain is non-zero, so with
    # finite filter outputs the others add ±0 and the sum is g·y exactly, with a zero as +0 (g·y + 0.0). Should
    # an output not be finite (0·inf is NaN), the whole sum is taken instead.
    rows = 2 * n_types if live else n_types
    finite = True
    for t in range(rows):
        for k in range(m):
            finite = finite & (abs(y_t[t, k]) < np.inf)
    for u_ in range(n_units):
        own = unit_type[u_]
        g, gd, nw, h = gk_own[u_], gm_own[u_], negw[u_], vh[u_]
        for k in range(m):
            if finite:
                a = g * y_t[own, k] + 0.0
                if live:
                    a = a + (gd * y_t[n_types + own, k] + 0.0)
            else:
                a = 0.0
                for t in range(n_types):
                    a += gk[u_, t] * y_t[t, k]
                if live:
                    b = 0.0
                    for t in range(n_types):
                        b += gm[u_, t] * y_t[n_types + t, k]
                    a = a + b
            w = a * nw
            c = a if (a >= w) | (a != a) else w
            v[u_, k] = c if (c <= h) | (c != c) else h
    rate, active, masked = units[0], units[1], units[2]
    _mv(v, ones_m, rate)  # rate = v @ 1 (np.dot(v, ones_m)), then rate *= scale_mean
    row = ring[pos]
    for i in range(n_units):
        r = rate[i] * scale_mean[i]
        total[i] = total[i] + r  # total += rate; total -= ring[pos]; ring[pos] = rate
        total[i] = total[i] - row[i]
        row[i] = r
        active[i] = 1.0 if total[i] > thr else 0.0  # _readout: active = total > thr (1.0 / 0.0)
        masked[i] = total[i] * active[i]
    _mv(members, active, sums[0])  # counts = members @ active
    _mv(members, masked, sums[1])  # sums = members @ masked
    return deep_live
