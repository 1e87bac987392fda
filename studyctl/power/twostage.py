"""Stage 2 of the two-stage power design: replicate studies drawn from the stored pool, analysed by the plan.

A replicate at size n takes the composition a full-engine replicate of that size has — people per stratum from
:func:`studyctl.protocol.allocate_strata` and, per allocation slot, the counterbalancing sequence the protocol's
planner gives it — and fills every (stratum, sequence) cell with people drawn without replacement from the pool's
people of that cell (``draw_rng(seed, n, replicate)``). Their metric rows go through the same analysis plan as a
full-engine replicate (its hypothesis tests, :func:`studyctl.analysis.execute.hypothesis_rows`, as a full-engine
replicate runs them); nothing is re-simulated, and each person's analysis units are computed once for the
whole pool (:mod:`studyctl.power.units`), so a replicate costs the tests themselves.

:func:`compare` states the design's error: per test row, the difference between two-stage and full-engine power
at the checked sizes, with the Monte-Carlo standard error of each (binomial, over its replicate count).
"""

from __future__ import annotations

import math
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from studyctl.errors import UsageError
from studyctl.power.pool import Pool
from studyctl.power.replicate import ROW_COLUMNS, ReplicateResult, power_rows
from studyctl.power.seeds import draw_rng, replicate_seeds
from studyctl.power.spec import PowerSpec
from studyctl.power.units import PoolUnits, replicate_rows
from studyctl.protocol import Planner, allocate_strata


def composition(protocol, seed: int, participants: int, replicate: int) -> dict[tuple[str, int | None], int]:  # noqa: ANN001
    """People per (stratum, sequence index) in a full-engine replicate of this size (sequence None: random orders)."""
    planner = Planner(protocol)
    study_seed = replicate_seeds(seed, participants, replicate).study_seed
    cells: dict[tuple[str, int | None], int] = {}
    for stratum, slot in allocate_strata(protocol, participants):
        key = (stratum, planner.sequence_index(study_seed, stratum, slot))
        cells[key] = cells.get(key, 0) + 1
    return cells


def cell_ids(members: pd.DataFrame, stratum: str, seq: int | None) -> np.ndarray:
    """The member ids of one (stratum, sequence) cell (sequence None: the whole stratum), in the pool's order."""
    mask = members["stratum"] == stratum
    if seq is not None:
        mask &= members["sequence"] == seq
    return members.loc[mask, "member"].to_numpy()


def draw_members(pool: Pool, cells: dict[tuple[str, int | None], int], rng: np.random.Generator,
                 members: pd.DataFrame | None = None,
                 index: dict[tuple[str, int | None], np.ndarray] | None = None) -> list[str]:
    """Member ids for every cell, without replacement within the pool (UsageError if a cell runs short).

    ``members``: draw from these rows of the pool's people instead (a bootstrap pool, where a person's row can
    repeat: the same person can then be drawn twice). ``index``: a cache of :func:`cell_ids` of those members
    (filled here), so a run of many replicates filters the pool once per cell, not once per replicate."""
    members = pool.members if members is None else members
    index = {} if index is None else index
    chosen: list[str] = []
    for (stratum, seq), count in cells.items():
        if (stratum, seq) not in index:
            index[(stratum, seq)] = cell_ids(members, stratum, seq)
        ids = index[(stratum, seq)]
        if ids.size < count:
            raise UsageError(
                f"the pool at {pool.path} has {ids.size} people of stratum {stratum!r}"
                + ("" if seq is None else f", sequence {seq}") + f", a replicate needs {count}; use a larger --pool"
            )
        chosen.extend(ids[rng.choice(ids.size, size=count, replace=False)].tolist())
    return chosen


def member_frames(pool: Pool) -> dict[str, pd.DataFrame]:
    """Each pool person's metric rows (the table of a replicate is its people's rows, in draw order)."""
    return dict(tuple(pool.metrics.groupby("participant", sort=False)))


class Stage2:
    """What every stage-2 replicate of one pool shares, prepared once: the protocol, each person's rows, the
    pool's units and each (stratum, sequence) cell's people (found once per pool, not once per replicate)."""

    def __init__(self, spec: PowerSpec, pool: Pool) -> None:
        self.spec, self.pool = spec, pool
        self.protocol = spec.load_protocol()
        self.by_member = member_frames(pool)
        self.units = PoolUnits(spec.plan, pool.metrics, spec.study_id)
        self.index: dict[tuple[str, int | None], np.ndarray] = {}

    def rows(self, chosen: list[str]) -> tuple:
        """The replicate's test rows (:data:`studyctl.power.replicate.ROW_COLUMNS` without size and index)."""
        return power_rows(replicate_rows(self.units, chosen, self.by_member))

    def draw(self, participants: int, replicate: int) -> list[str]:
        """The people of stage-2 replicate ``replicate`` at ``participants``: the full-engine replicate's
        (stratum, sequence) composition, drawn from the pool with the replicate's own seed."""
        cells = composition(self.protocol, self.spec.seed, participants, replicate)
        return draw_members(self.pool, cells, draw_rng(self.spec.seed, participants, replicate), index=self.index)

    def replicate(self, participants: int, replicate: int) -> ReplicateResult:
        """Stage-2 replicate ``replicate`` at size ``participants``: draw its people, run the plan's hypothesis
        tests on their metric rows."""
        t0, c0 = time.perf_counter(), time.process_time()
        rows = self.rows(self.draw(participants, replicate))
        return ReplicateResult(
            participants=int(participants), replicate=int(replicate), rows=rows, sessions_completed=0,
            trials_completed=0, trials_not_completed=0, clipped=0, seconds=time.perf_counter() - t0,
            cpu_seconds=time.process_time() - c0, peak_rss_mb=math.nan,
            worker=f"{socket.gethostname()}:{os.getpid()}",
        )

    def rows_frame(self, members: pd.DataFrame, participants: int, replicate: int,
                   rng: np.random.Generator) -> pd.DataFrame:
        """A replicate drawn with ``rng`` from ``members`` (e.g. a bootstrap pool) as a rows frame."""
        cells = composition(self.protocol, self.spec.seed, participants, replicate)
        chosen = draw_members(self.pool, cells, rng, members)
        data = [(participants, replicate, *row) for row in self.rows(chosen)]
        return pd.DataFrame(data, columns=list(ROW_COLUMNS))


#: The pool a worker process last loaded for :func:`draw_batch` (one at a time: a run uses one pool).
_LOADED: dict[tuple, Stage2] = {}


def _worker_stage2(spec: PowerSpec, path: str, chunks: int, size: int) -> Stage2:
    """The :class:`Stage2` of the pool file at ``path``, loaded once per worker process."""
    import sqlite3

    from studyctl.power.pool import PoolFile

    key = (path, chunks, size, spec.plan_sha256)
    if key not in _LOADED:
        _LOADED.clear()
        pf = PoolFile(Path(path), sqlite3.connect(path))
        try:
            pool = pf.load(chunks, size, 0)
        finally:
            pf.close()
        _LOADED[key] = Stage2(spec, pool)
    return _LOADED[key]


def draw_batch(spec: PowerSpec, path: str, chunks: int, size: int, participants: int, start: int,
               stop: int) -> list[ReplicateResult]:
    """Stage-2 replicates ``start`` … ``stop - 1`` at ``participants`` from the pool file at ``path`` (its first
    ``chunks`` chunks of ``size`` people): a Dask task, coarse enough that scheduling is a small part of it."""
    stage2 = _worker_stage2(spec, path, chunks, size)
    return [stage2.replicate(participants, r) for r in range(start, stop)]


def batches(todo: list[tuple[int, int]], per_task: int) -> list[tuple[int, int, int]]:
    """Runs of consecutive replicates of one size, at most ``per_task`` long: (n, start, stop)."""
    out: list[tuple[int, int, int]] = []
    for n, r in todo:
        if out and out[-1][0] == n and out[-1][2] == r and out[-1][2] - out[-1][1] < per_task:
            out[-1] = (n, out[-1][1], r + 1)
        else:
            out.append((n, r, r + 1))
    return out


@dataclass(frozen=True)
class PowerError:
    """Two-stage vs full-engine power at the checked sizes (``to_frame()``: one row per test row and size).

    Per row: the difference in percentage points and its standard error from all three Monte-Carlo sources —
    the full-engine replicates (binomial), the stage-2 draws (binomial) and the pool's own sampling error (pool
    bootstrap, :mod:`studyctl.power.bootstrap`; NaN when not measured) — and ``z`` = difference / that SE. The
    design is unbiased (a random study from a random pool is a random study), so the z values should look like
    standard normal draws; their sum of squares is ``chi2`` over ``rows``.
    """

    frame: pd.DataFrame
    sizes: tuple[int, ...]
    exact_replicates: int
    two_stage_replicates: int
    pool_people: int | None = None
    boot_pools: int = 0
    boot_replicates: int = 0

    def to_frame(self) -> pd.DataFrame:
        return self.frame.copy()

    @property
    def max_abs_pp(self) -> float:
        return float(self.frame["diff_pp"].abs().max()) if not self.frame.empty else math.nan

    def summary(self) -> dict:
        f = self.frame
        worst = f.loc[f["diff_pp"].abs().idxmax()] if not f.empty else None
        z = f["z"].to_numpy(dtype=float) if not f.empty else np.zeros(0)
        z = z[np.isfinite(z)]
        pool_se = f["pool_se_pp"].to_numpy(dtype=float) if not f.empty else np.zeros(0)
        return {
            "power_error_pp": self.max_abs_pp,
            # the difference is only meaningful against its SE: the worst row's, and every source's largest
            "power_error_se_pp": math.nan if worst is None else float(worst["combined_se_pp"]),
            "checked_sizes": list(self.sizes),
            "exact_replicates": self.exact_replicates,
            "two_stage_replicates": self.two_stage_replicates,
            "pool_people": self.pool_people,
            "boot_pools": self.boot_pools,
            "boot_replicates": self.boot_replicates,
            "worst": None if worst is None else {k: (v.item() if hasattr(v, "item") else v)
                                                 for k, v in worst.items()},
            "mc_se_exact_pp_max": float(f["mc_se_exact_pp"].max()) if not f.empty else math.nan,
            "mc_se_two_stage_pp_max": float(f["mc_se_two_stage_pp"].max()) if not f.empty else math.nan,
            "pool_se_pp_max": float(np.nanmax(pool_se)) if np.isfinite(pool_se).any() else math.nan,
            "combined_se_pp_max": float(f["combined_se_pp"].max()) if not f.empty else math.nan,
            "mean_diff_pp": float(f["diff_pp"].mean()) if not f.empty else math.nan,
            "rows": int(z.size),
            "chi2": float((z ** 2).sum()),
            "rows_abs_z_over_2": int((np.abs(z) > 2).sum()),
            # the pool's SE falls as 1/sqrt(people): the pool that would bring the worst row's to 2 pp
            "pool_people_for_2pp_se": (math.ceil(self.pool_people * (float(np.nanmax(pool_se)) / 2.0) ** 2)
                                       if self.pool_people and np.isfinite(pool_se).any() else None),
        }


def compare(two_stage: pd.DataFrame, exact: pd.DataFrame, sizes: tuple[int, ...],
            pool_error: pd.DataFrame | None = None) -> PowerError:
    """Per non-post-hoc test row at ``sizes``: two-stage minus full-engine power in percentage points, with the
    binomial Monte-Carlo standard error of each (sqrt(p(1-p)/R) × 100), the pool's standard error from
    ``pool_error`` (:meth:`studyctl.power.bootstrap.PoolError.to_frame`; without it the pool's error is not in
    the combined SE, which then understates the difference's spread) and z = difference / combined SE."""
    # groups too: a model's terms (group, condition, their interaction) are rows of one test, metric and split
    keys = ["participants", "test_id", "metric", "split", "kind", "groups"]
    a = two_stage[(two_stage["kind"] != "posthoc") & two_stage["participants"].isin(sizes)]
    b = exact[(exact["kind"] != "posthoc") & exact["participants"].isin(sizes)]
    m = a.merge(b, on=keys, suffixes=("_two_stage", "_exact"))
    out = pd.DataFrame({k: m[k] for k in keys})
    for side in ("two_stage", "exact"):
        p, r = m[f"power_{side}"].astype(float), m[f"replicates_{side}"].astype(float)
        out[f"power_{side}"] = p
        out[f"replicates_{side}"] = r.astype(int)
        out[f"mc_se_{side}_pp"] = 100 * np.sqrt(p * (1 - p) / r.clip(lower=1))
        # the Wilson interval too: at p = 0 or 1 the binomial SE is 0 however few replicates there were
        out[f"ci_low_{side}"] = m[f"power_ci_low_{side}"].astype(float)
        out[f"ci_high_{side}"] = m[f"power_ci_high_{side}"].astype(float)
    people = boots = boot_reps = 0
    if pool_error is not None and not pool_error.empty:
        pe = pool_error[pool_error["kind"] != "posthoc"][[*keys, "pool_se"]]
        out = out.merge(pe, on=keys, how="left")
        out["pool_se_pp"] = 100 * out.pop("pool_se").astype(float)
        people = int(pool_error["pool_people"].iloc[0])
        boots, boot_reps = int(pool_error["boot_pools"].iloc[0]), int(pool_error["boot_replicates"].iloc[0])
    else:
        out["pool_se_pp"] = np.nan
    out["diff_pp"] = 100 * (out["power_two_stage"] - out["power_exact"])
    binom = out["mc_se_two_stage_pp"] ** 2 + out["mc_se_exact_pp"] ** 2
    out["combined_se_pp"] = np.sqrt(binom + out["pool_se_pp"].fillna(0.0) ** 2)
    # a row at 0 or 1 on both sides has SE 0 and difference 0: no evidence either way (z left undefined)
    with np.errstate(divide="ignore", invalid="ignore"):
        out["z"] = np.where(out["combined_se_pp"] > 0, out["diff_pp"] / out["combined_se_pp"], np.nan)
    reps_e = int(b["replicates"].max()) if not b.empty else 0
    reps_t = int(a["replicates"].max()) if not a.empty else 0
    return PowerError(out.reset_index(drop=True), tuple(sizes), reps_e, reps_t, people or None, boots, boot_reps)
