"""Studentized range distribution: survival function computed directly, and its quantile.

The survival function is never formed as 1 − cdf. For the range R of k standard normals,

    P(R > w) = k ∫ φ(z) Q(z + w) Σ_{i=0}^{k−2} B(z)^i A(z)^{k−2−i} dz,
    B = Q(z) = 1 − Φ(z),  A = Φ(z + w) − Φ(z),

which follows from B^{k−1} − A^{k−1} = (B − A) Σ B^i A^{k−2−i} with B − A = Q(z + w); every
term is positive. The studentized range with ν degrees of freedom integrates this over the
distribution of s = sqrt(χ²_ν/ν). Both integrals use two Gauss-Legendre panels split at the peak
of a log-concave bound of the integrand (found by Newton's method); the bound's curvature gives
windows that provably hold everything within e^-48 of the peak. Everything is summed in log space,
so tails far below 1e-300 keep their relative accuracy until they underflow. log P(R > w) is
tabulated per k on 0 ≤ w ≤ 60 (step 0.015, 2×64 nodes each) and read through a quintic
spline, which keeps a Tukey call in the millisecond range. Building one table costs ~0.3 s, which
was the whole of a report's first Tukey call, so the spline coefficients for k = 3…_K_SHIPPED ship
in the wheel (``studentized_range_tables.npz``, written by ``python -m
studyctl.stats.studentized_range_tables``); other k are built on first use. k = 2 uses the exact identity
P(Q > q) = 2·P(t_ν > q/√2).
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy import special

from studyctl.errors import StatsInputError

from ._validate import check_probability

# scipy.interpolate and scipy.optimize (together ~0.25 s CPU) are imported where a spline is built or a quantile
# solved, so importing studyctl.stats (test collection, a command that only checks a plan) does not pay for them.
if TYPE_CHECKING:
    from scipy import interpolate

_NZ = 64  # Gauss-Legendre nodes per panel of the z integral (two panels split at the peak)
_NS = 48  # nodes per panel of the s integral
_W_MAX = 60.0  # log P(R > w) is tabulated on [0, _W_MAX]; beyond, it is integrated directly
_W_STEP = 0.015
_DROP = 48.0  # windows reach where the log integrand is this far below its peak (e^-48 ≈ 1e-21)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_XZ, _WZ = np.polynomial.legendre.leggauss(_NZ)
_XS, _WS = np.polynomial.legendre.leggauss(_NS)
_LOG_WZ = np.log(_WZ)
_LOG_WS = np.log(_WS)
TABLE_FILE = "studentized_range_tables.npz"


def _check(k: int, df: float) -> tuple[int, float]:
    if isinstance(k, bool) or int(k) != k or k < 2:
        raise StatsInputError(f"k (number of groups) must be an integer ≥ 2, got {k!r}")
    df = float(df)
    if not (df > 0):
        raise StatsInputError(f"df must be > 0 (math.inf for the normal case), got {df!r}")
    return int(k), df


def _phi_diff(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Φ(hi) − Φ(lo) for hi ≥ lo without cancellation in either tail."""
    # Mirror so that the interval's centre is ≥ 0 and take Q(lo) − Q(hi): both terms are upper
    # tails (relative accuracy) when lo ≥ 0; otherwise the interval straddles 0 and the result is
    # not small compared with its absolute error.
    flip = (lo + hi) < 0
    a = np.where(flip, -hi, lo)
    b = np.where(flip, -lo, hi)
    return special.ndtr(-a) - special.ndtr(-b)


def _mills(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse Mills ratio λ(x) = φ(x)/Q(x) and its derivative λ(λ − x) (0 < λ' < 1)."""
    lam = np.exp(-0.5 * x * x - _LOG_SQRT_2PI - special.log_ndtr(-x))
    return lam, lam * (lam - x)


def _panels(peak: np.ndarray, left: np.ndarray, right: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nodes of two Gauss-Legendre panels [peak − left, peak] and [peak, peak + right]; log Jacobians."""
    hl, hr = 0.5 * left, 0.5 * right
    nodes = np.concatenate(((peak - hl)[..., None] + hl[..., None] * x, (peak + hr)[..., None] + hr[..., None] * x), -1)
    n = x.size
    shape = hl.shape + (n,)
    logjac = np.concatenate(
        (np.broadcast_to(np.log(hl)[..., None], shape), np.broadcast_to(np.log(hr)[..., None], shape)), -1
    )
    return nodes, logjac


_SPLINE_DEGREE = 5


def range_grid() -> np.ndarray:
    """The w grid on which log P(R > w) is tabulated."""
    return np.linspace(0.0, _W_MAX, int(round(_W_MAX / _W_STEP)) + 1)


def build_range_table(k: int) -> interpolate.BSpline:
    """Quintic spline through log P(R > w) on :func:`range_grid` (by quadrature; ~0.3 s)."""
    from scipy import interpolate

    grid = range_grid()
    return interpolate.make_interp_spline(grid, _log_range_sf_direct(grid, k), k=_SPLINE_DEGREE)


@lru_cache(maxsize=64)
def _range_table(k: int) -> interpolate.BSpline:
    from scipy import interpolate

    shipped = _shipped_coefficients(k)
    if shipped is not None:
        # construct_fast: the knots were validated when the table was written
        return interpolate.BSpline.construct_fast(*shipped, _SPLINE_DEGREE)
    return build_range_table(k)


def _shipped_coefficients(k: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(knots, coefficients) of k's spline shipped beside this module, or None when absent, written for
    another grid or not covering k (then the table is built on first use)."""
    path = Path(__file__).with_name(TABLE_FILE)
    if not path.is_file():
        return None
    with np.load(path) as data:
        if f"k{k}" not in data.files:
            return None
        if not np.array_equal(data["grid_spec"], np.array([_W_MAX, _W_STEP, _SPLINE_DEGREE, _NZ], dtype=float)):
            return None
        return data["knots"], data[f"k{k}"]


def log_range_sf(w: np.ndarray, k: int) -> np.ndarray:
    """log P(R > w) for the range R of k independent standard normals (w ≥ 0, any shape)."""
    w = np.asarray(w, dtype=np.float64)
    out = np.empty(w.shape)
    inside = w <= _W_MAX
    out[inside] = np.minimum(0.0, _range_table(k)(w[inside]))
    if not np.all(inside):
        out[~inside] = _log_range_sf_direct(w[~inside], k)
    return out


def _log_range_sf_direct(w: np.ndarray, k: int) -> np.ndarray:
    """log P(R > w) by quadrature (see module notes).

    The integrand lies between the log-concave bound g(z) = φ(z)Q(z+w)Q(z)^{k−2} and (k−1)·g
    (because A ≤ B). Newton's method finds the peak z* of g; as −(log g)'' ≥ 1 everywhere and grows
    to the right, z* − sqrt(2D) and z* + sqrt(2D/−(log g)''(z*)) bound the region within D of the
    peak, and a Gauss-Legendre panel on each side of z* integrates it.
    """
    w = np.asarray(w, dtype=np.float64)
    z = np.minimum(-0.5 * w, -1.0)
    for _ in range(40):  # damped Newton on the concave log g
        lam_w, dlam_w = _mills(z + w)
        lam_z, dlam_z = _mills(z)
        grad = -z - lam_w - (k - 2) * lam_z
        curv = 1.0 + dlam_w + (k - 2) * dlam_z
        step = np.minimum(np.maximum(grad / curv, -3.0), 3.0)
        z = z + step
        if np.max(np.abs(step)) < 1e-10:
            break
    _, dlam_w = _mills(z + w)
    _, dlam_z = _mills(z)
    curv = 1.0 + dlam_w + (k - 2) * dlam_z
    reach = 2.0 * (_DROP + math.log(k - 1))
    nodes, logjac = _panels(z, np.full(z.shape, math.sqrt(reach)), np.sqrt(reach / curv), _XZ)
    wz = np.concatenate((_LOG_WZ, _LOG_WZ))
    zw = nodes + w[..., None]
    b = special.ndtr(-nodes)
    a = _phi_diff(nodes, zw)
    s = np.ones_like(nodes)
    bpow = np.ones_like(nodes)
    for _ in range(k - 2):  # S_j = A·S_{j−1} + B^j  →  Σ_{i=0}^{j} B^i A^{j−i}
        bpow = bpow * b
        s = a * s + bpow
    with np.errstate(divide="ignore"):
        log_terms = wz + logjac - 0.5 * nodes * nodes - _LOG_SQRT_2PI + special.log_ndtr(-zw) + np.log(s)
    return math.log(k) + special.logsumexp(log_terms, axis=-1)


def _log_sf(q: np.ndarray, k: int, df: float) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    out = np.zeros(q.shape)  # log 1 for q ≤ 0
    out[np.isposinf(q)] = -np.inf  # P(Q > ∞) = 0; the quadrature's Newton step would give NaN
    pos = (q > 0) & np.isfinite(q)
    if not np.any(pos):
        return out
    qp = q[pos]
    if k == 2:  # exact: Q = √2 |t|
        if math.isinf(df):
            out[pos] = special.log_ndtr(-qp / math.sqrt(2.0)) + math.log(2.0)
        else:
            out[pos] = np.log(2.0 * special.stdtr(df, -qp / math.sqrt(2.0)))
        return out
    if math.isinf(df) or df > 1e7:
        out[pos] = log_range_sf(qp, k)
        return out
    # s = sqrt(χ²_ν/ν) has log density c + (ν−1)log s − νs²/2. The integrand lies between the
    # concave (in s, for ν ≥ 1) bound h(s) = density·2Q(qs/√2) and k(k−1)/2 times it, with
    # −(log h)'' ≥ ν: the window within D of the peak is at most sqrt(2D/ν) wide on each side.
    log_c = math.log(2.0) + 0.5 * df * math.log(0.5 * df) - math.lgamma(0.5 * df)
    c = qp / math.sqrt(2.0)
    s = np.ones_like(qp)
    for _ in range(60):  # damped Newton in u = log s (concave there for every ν > 0)
        lam, dlam = _mills(c * s)
        grad = df - df * s * s - c * s * lam
        curv = 2.0 * df * s * s + c * s * lam + (c * s) ** 2 * dlam
        step = np.minimum(np.maximum(grad / curv, -2.0), 2.0)
        s = s * np.exp(step)
        if np.max(np.abs(step)) < 1e-10:
            break
    # curvature bounds of −log h: ≥ ν + (ν−1)/s*² left of the peak, ≥ ν + c²λ'(cs*) right of it
    two_d = 2.0 * (_DROP + math.log(k * (k - 1) / 2.0))
    _, dlam = _mills(c * s)
    if df >= 1.0:
        left = np.minimum(s, np.sqrt(two_d / (df + (df - 1.0) / (s * s))))
    else:
        left = s
    right = np.sqrt(two_d / (df + c * c * dlam))
    nodes, logjac = _panels(s, np.maximum(left, 1e-300), right, _XS)
    ws = np.concatenate((_LOG_WS, _LOG_WS))
    log_f = log_c + (df - 1.0) * np.log(nodes) - 0.5 * df * nodes * nodes
    log_pr = log_range_sf(qp[:, None] * nodes, k)
    out[pos] = special.logsumexp(ws + logjac + log_f + log_pr, axis=1)
    return out


def studentized_range_sf(q: float | np.ndarray, k: int, df: float) -> float | np.ndarray:
    r"""Survival function P(Q > q) of the studentized range of k means with ``df`` error df.

    Parameters
    ----------
    q : float or array_like
        Studentized range value(s); q ≤ 0 gives 1.
    k : int
        Number of groups (≥ 2).
    df : float
        Error degrees of freedom ν > 0; ``math.inf`` for a known variance (normal range).

    Returns
    -------
    float or numpy.ndarray
        P(Q > q), computed directly (not as 1 − cdf), with relative accuracy kept in the far tail.

    Notes
    -----
    .. math::

        P(Q > q) = \int_0^\infty f_\nu(s)\, k \int \phi(z)\, Q(z + qs)
        \sum_{i=0}^{k-2} B^i A^{k-2-i}\, dz\, ds

    with B = Q(z), A = Φ(z + qs) − Φ(z) and f_ν the density of sqrt(χ²_ν/ν). For k = 2 the exact
    identity P(Q > q) = 2 P(t_ν > q/√2) is used.

    References
    ----------
    Lund & Lund (1983), Algorithm AS 190, Appl. Statist. 32:204-210. Copenhaver & Holland (1988),
    J. Statist. Comput. Simul. 30:1-15.

    Examples
    --------
    >>> from studyctl.stats import studentized_range_sf
    >>> round(studentized_range_sf(3.5, 3, 10), 7)
    0.0771033
    """
    k, df = _check(k, df)
    try:
        arr = np.asarray(q, dtype=np.float64)
    except (TypeError, ValueError):
        raise StatsInputError(f"q must be a number or an array of numbers, got {q!r}") from None
    if np.isnan(arr).any():
        raise StatsInputError("q contains NaN; the studentized range survival function needs numbers (q = inf gives 0)")
    res = np.exp(_log_sf(arr.reshape(-1), k, df)).reshape(arr.shape)
    return float(res) if res.ndim == 0 else res


_PPF_GRID = np.arange(1, 25) * 0.5  # first bracket of the quantile, evaluated in one vectorised call


@lru_cache(maxsize=256)
def _ppf_cached(p: float, k: int, df: float) -> float:
    from scipy import optimize

    target = math.log1p(-p)  # log upper-tail probability α = 1 − p

    def f(q: float) -> float:
        return float(_log_sf(np.array([q]), k, df)[0]) - target

    def polish(lo: float, hi: float) -> float:
        return float(optimize.brentq(f, lo, hi, xtol=1e-13, rtol=4e-15))

    # Each scalar evaluation costs a Newton solve and two quadratures, and a report's first Tukey call
    # used to spend most of its time here; so the bracket comes from vectorised calls (a coarse grid,
    # then two narrow pairs around the secant guess) and brentq only polishes the last digits.
    vals = _log_sf(_PPF_GRID, k, df) - target
    below = np.flatnonzero(vals <= 0)
    if below.size == 0:
        lo, hi = float(_PPF_GRID[-1]), float(_PPF_GRID[-1]) * 2.0
        while f(hi) > 0:
            lo, hi = hi, hi * 2.0
            if hi > 1e6:
                raise StatsInputError(f"studentized range quantile not found for p={p}, k={k}, df={df}")
        return polish(lo, hi)
    j = int(below[0])
    if j == 0:
        return polish(0.0, float(_PPF_GRID[0]))
    lo, hi, f_lo, f_hi = float(_PPF_GRID[j - 1]), float(_PPF_GRID[j]), float(vals[j - 1]), float(vals[j])
    if f_lo > f_hi:  # narrow to ±0.02 around the secant guess
        guess = lo + (hi - lo) * f_lo / (f_lo - f_hi)
        pair = np.clip(np.array([guess - 0.02, guess + 0.02]), lo, hi)
        f_pair = _log_sf(pair, k, df) - target
        if f_pair[0] > 0:
            lo = float(pair[0])
        if f_pair[1] <= 0:
            hi = float(pair[1])
    # On a bracket this narrow, log P(Q > q) is smooth enough that inverse interpolation through 7 nodes is
    # exact to rounding; the nodes must still bracket the root monotonically, else brentq decides.
    # (When the secant guess missed by more than 0.02 the bracket is still wide: brentq from there, without
    # evaluating the 7 nodes first.)
    if hi - lo <= 0.05:
        nodes = np.linspace(lo, hi, 7)
        f_nodes = _log_sf(nodes, k, df) - target
        if np.all(np.diff(f_nodes) < 0) and f_nodes[0] > 0 >= f_nodes[-1]:
            root = _neville_at_zero(f_nodes, nodes)
            if lo <= root <= hi:
                return root
    return polish(lo, hi)


def _neville_at_zero(f: np.ndarray, q: np.ndarray) -> float:
    """Value at f = 0 of the polynomial through the points (f_i, q_i), by Neville's scheme (deterministic: scipy's
    BarycentricInterpolator permutes its nodes with a random generator, which changed the last bits between
    processes)."""
    p = [float(v) for v in q]
    x = [float(v) for v in f]
    n = len(p)
    for level in range(1, n):
        for i in range(n - level):
            j = i + level
            p[i] = (x[j] * p[i] - x[i] * p[i + 1]) / (x[j] - x[i])
    return p[0]


def studentized_range_ppf(p: float, k: int, df: float) -> float:
    """Quantile q with P(Q ≤ q) = p of the studentized range (root of the log survival function).

    Parameters
    ----------
    p : float
        Probability in (0, 1), e.g. the confidence level 0.95.
    k, df : int, float
        As in :func:`studentized_range_sf`.

    Returns
    -------
    float
        The quantile, solved to ~1e-13 (R's ``qtukey`` is documented as accurate to 4 decimals).

    Examples
    --------
    >>> from studyctl.stats import studentized_range_ppf
    >>> round(studentized_range_ppf(0.95, 3, 10), 4)
    3.8768
    """
    k, df = _check(k, df)
    return _ppf_cached(check_probability(p, "p"), k, df)
