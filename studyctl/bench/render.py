"""``studyctl bench render``: one 1 kHz force-rendering tick (depth query + interpolation + clamping), and
interpolation variants' speed against error.

Headline figures (``render_us_median``, ``render_us_p99``): :meth:`ForceRenderer.render` with the default
parameters on the seed 002 curved phantom (31 × 26-node surface, 1500 triangles: the exact nearest-triangle
depth query does real work) along a 1 kHz press-and-sweep trajectory that enters and leaves the tissue; the
same on the seed 003 block (six 159 × 59 matrices, flat surface) as ``render_us_*_block003``.

Peer, same run: the textbook SciPy tick — exact depth by a vectorised point-to-triangle distance over all
faces (NumPy) and ``RegularGridInterpolator(method="linear")`` for the table — on the same trajectory.

Variant table: ``nearest``, ``linear``, ``cubic``, ``powerlaw`` on the full table and on tables coarsened ×2
and ×4, each with ``force_error_pct`` = 100 · RMS(f − f_ref)/RMS(f_ref) (and ``max_error_pct`` = max |f − f_ref|
over max f_ref) against SciPy's full-resolution cubic reference at random points of the mapped volume, and
the median µs per look-up and per full tick.
"""

from __future__ import annotations

import math
import time

import numpy as np

from studyctl.bench import BenchResult
from studyctl.models.force_lookup import DEFAULT_INTERPOLATION, INTERPOLATIONS, make_lookup
from studyctl.models.force_render import ForceRenderer, Placement, RenderParams, reference_forces
from studyctl.models.surface_mesh import SurfaceMesh, closest_points_on_triangles
from studyctl.models.synthetic_phantom import curved_phantom_002, silicone_block_003


def _trajectory(mesh: SurfaceMesh, placement: Placement, seconds: float, rate_hz: float = 1000.0) -> list:
    """Press-and-sweep at 1 kHz: x sweeps at 30 mm/s, y steps along lines, z dips 6 mm at 2 Hz."""
    x0, x1, y0, y1 = mesh.footprint_mm
    n = int(seconds * rate_hz)
    t = np.arange(n) / rate_hz
    span = (x1 - x0) - 10.0
    phase = (30.0 * t) % (2 * span)
    lx = x0 + 5.0 + np.where(phase < span, phase, 2 * span - phase)
    ly = y0 + 5.0 + ((30.0 * t) // span * 7.0) % ((y1 - y0) - 10.0)
    pts = []
    for k in range(n):
        h = mesh.height_at(float(lx[k]), float(ly[k])) or 0.0
        z = h + 1.0 - 3.5 * (1.0 - math.cos(2 * math.pi * 2.0 * t[k]))  # 1 mm above to 6 mm below
        pts.append(placement.to_world(float(lx[k]), float(ly[k]), z))
    return pts


def _time_each(fn, args: list, warmup: int = 200) -> np.ndarray:
    for a in args[:warmup]:
        fn(*a)
    clock = time.perf_counter
    out = np.empty(len(args))
    for i, a in enumerate(args):
        t0 = clock()
        fn(*a)
        out[i] = clock() - t0
    return out * 1e6


def _scipy_tick_factory(smap, mesh: SurfaceMesh, placement: Placement):
    from scipy.interpolate import RegularGridInterpolator

    rgi = RegularGridInterpolator((smap.depths_mm, smap.xs_mm, smap.ys_mm), smap.normal_n, method="linear")
    tri = mesh.vertices[mesh.faces]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    lo = (smap.xs_mm[0], smap.ys_mm[0], smap.depths_mm[0])
    hi = (smap.xs_mm[-1], smap.ys_mm[-1], smap.depths_mm[-1])

    def tick(x: float, y: float, z: float) -> float:
        lx, ly, lz = placement.to_local(x, y, z)
        h = mesh.height_at(lx, ly)
        if h is None or lz >= h:
            return 0.0
        p = np.array([lx, ly, lz])
        q = closest_points_on_triangles(p, a, b, c)
        d2 = ((q - p) ** 2).sum(axis=1)
        k = int(np.argmin(d2))
        depth = math.sqrt(d2[k])
        qx, qy = q[k, 0], q[k, 1]
        if not (lo[0] <= qx <= hi[0] and lo[1] <= qy <= hi[1]):
            return 0.0
        f = float(rgi([[min(max(depth, lo[2]), hi[2]), qx, qy]])[0])
        return min(max(f, 0.0), 3.3)

    return tick


def _variant_rows(name: str, smap, mesh, placement, traj, rng, n_points: int, n_ticks: int) -> list[dict]:
    x0, x1, y0, y1 = smap.extent_mm
    pts = np.column_stack(
        [
            rng.uniform(x0, x1, n_points),
            rng.uniform(y0, y1, n_points),
            rng.uniform(smap.depths_mm[0], smap.depths_mm[-1], n_points),
        ]
    )
    ref = reference_forces(smap, pts)
    rms_ref = float(np.sqrt(np.mean(ref**2)))
    rows = []
    args = [tuple(p) for p in pts.tolist()]
    for interp in INTERPOLATIONS:
        for sub in (1, 2, 4):
            table = smap.subsample(sub)
            look = make_lookup(table, interp)
            f = np.array([look(*a)[0] for a in args])
            lookup_us = _time_each(look, args[: min(len(args), 2000)], warmup=50)
            renderer = ForceRenderer(smap, mesh, RenderParams(interpolation=interp, subsample=sub), placement)
            tick_us = _time_each(renderer.render, traj[:n_ticks], warmup=50)
            rows.append(
                {
                    "table": name,
                    "interpolation": interp,
                    "subsample": sub,
                    "nodes": f"{table.shape[1]}x{table.shape[2]}x{table.shape[0]}",
                    "force_error_pct": float(100.0 * np.sqrt(np.mean((f - ref) ** 2)) / rms_ref),
                    "max_error_pct": float(100.0 * np.max(np.abs(f - ref)) / np.max(ref)),
                    "lookup_us_median": float(np.median(lookup_us)),
                    "tick_us_median": float(np.median(tick_us)),
                    "default": interp == DEFAULT_INTERPOLATION and sub == 1,
                }
            )
    return rows


def run(quick: bool = False) -> BenchResult:
    rng = np.random.default_rng(7)
    seconds = 1.0 if quick else 10.0
    curved = curved_phantom_002(np.random.default_rng(0))
    mesh002 = SurfaceMesh.from_height_grid(curved.surface_xs_mm, curved.surface_ys_mm, curved.surface_heights_mm)
    mesh002.warm(float(curved.stiffness.depths_mm[-1]) + 3.0)
    place002 = Placement(30.0, (45.0, 37.5))
    block = silicone_block_003(np.random.default_rng(0))
    mesh003 = SurfaceMesh.from_height_grid(block.surface_xs_mm, block.surface_ys_mm, block.surface_heights_mm)
    mesh003.warm(10.0)
    place003 = Placement(90.0, (60.0, 60.0))

    traj002 = _trajectory(mesh002, place002, seconds)
    traj003 = _trajectory(mesh003, place003, seconds)
    r002 = ForceRenderer(curved.stiffness, mesh002, RenderParams(), place002)
    r003 = ForceRenderer(block.stiffness, mesh003, RenderParams(), place003)
    us002 = _time_each(r002.render, traj002)
    us003 = _time_each(r003.render, traj003)
    contact = float(np.mean([r002.render(*p)[6] for p in traj002]))

    peer_ticks = traj002[:: 10 if quick else 4]
    peer002 = _time_each(_scipy_tick_factory(curved.stiffness, mesh002, place002), peer_ticks, warmup=20)

    # Exactness of the depth query on this run's trajectory (brute force over all triangles).
    sample = np.array([place002.to_local(*p) for p in traj002[:: 20 if quick else 5]])
    fast = np.array([mesh002.closest_tuple(*p)[0] for p in sample.tolist()])
    brute = mesh002.brute_force_distance(sample)
    depth_err = float(np.max(np.abs(fast - brute)))

    n_points, n_ticks = (300, 300) if quick else (4000, 3000)
    rows = _variant_rows("seed003 159x59x6", block.stiffness, mesh003, place003, traj003, rng, n_points, n_ticks)
    rows += _variant_rows("seed002 57x47x3", curved.stiffness, mesh002, place002, traj002, rng, n_points, n_ticks)
    default003 = next(r for r in rows if r["default"] and r["table"].startswith("seed003"))
    default002 = next(r for r in rows if r["default"] and r["table"].startswith("seed002"))

    figures = {
        "render_us_median": float(np.median(us002)),
        "render_us_p99": float(np.percentile(us002, 99)),
        "render_us_median_block003": float(np.median(us003)),
        "render_us_p99_block003": float(np.percentile(us003, 99)),
        "default_force_error_pct": default003["force_error_pct"],
        "default_force_error_pct_seed002": default002["force_error_pct"],
        "depth_max_error_mm": depth_err,
        "contact_fraction": contact,
        "ticks": float(len(us002)),
    }
    peers = {
        "render_us_median": float(np.median(peer002)),
        "render_us_p99": float(np.percentile(peer002, 99)),
    }
    notes = [
        "render_us_*: ForceRenderer.render per 1 kHz tick (placement transform, exact nearest-triangle depth, "
        f"{DEFAULT_INTERPOLATION} interpolation, clamping, retraction rule, horizontal direction) on the seed 002 "
        "curved phantom (1500 triangles) along a press-and-sweep trajectory; *_block003 on the seed 003 block.",
        "peers: the same tick with NumPy brute-force point-to-triangle depth and SciPy RegularGridInterpolator "
        "(linear), same trajectory (every 4th tick).",
        "force_error_pct = 100·RMS(f − f_ref)/RMS(f_ref) at random points of the mapped volume; f_ref = SciPy "
        "cubic splines in x, y on the full table and an interpolating spline of degree min(3, depths − 1) in depth.",
        "depth_max_error_mm: largest difference between the indexed depth query and brute force on this run's "
        "trajectory samples.",
        "Synthetic phantoms (documented approximations, studyctl.models.synthetic_phantom), not measurements.",
    ]
    return BenchResult("render", figures, peers, {"interpolation variants": rows}, notes)
