"""The pool's own sampling error: a pool bootstrap of stage-2 power.

A two-stage power estimate has two Monte-Carlo errors. The replicate draws (binomial, sqrt(p(1-p)/R)) shrink
with more stage-2 replicates; the pool's error does not: a pool of M people is one sample of the population, and
stage-2 power is the power *of that sample* (every replicate resamples the same M people). Averaged over pools it
is unbiased (the power of a random n-subset of a random pool is the power of a random study), but one pool's value
scatters around the population's by roughly 0.4/sqrt(M/n) near 50 % power for a normal-theory test (the projection
of an n-person test on one person has variance ≈ φ²/n, so the order-n U-statistic over M people has ≈ nφ²/M). At
20 × n that is up to ~9 pp, which is what two disjoint halves of one pool showed (issue 22: up to 11 pp apart).

:func:`pool_bootstrap` measures it: B bootstrap pools (the pool's people resampled with replacement within each
(stratum, sequence) cell, so every cell keeps its size), R_b stage-2 replicates from each, and per test row

    pool variance = S²(P̂_b) − mean(P̂_b (1 − P̂_b)) / (R_b − 1)     (clipped at 0)

the between-pool variance of the bootstrap powers minus their own binomial part (E[P̂(1−P̂)] = p(1−p)(1−1/R)).
Someone drawn twice into one replicate counts as two participants (two copies of the same simulated person).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from studyctl.power.summary import KEY, summarise

#: Spawn-key tag of the bootstrap's streams (beside POOL_KEY = -1 and DRAW_KEY = -2 in seeds.py).
BOOT_KEY = -3
#: Columns of :meth:`PoolError.to_frame`.
COLUMNS = ("participants", *KEY, "boot_pools", "boot_replicates", "boot_power_mean", "boot_power_sd",
           "pool_se", "pool_people")


def boot_rng(master_seed: int, participants: int, b: int) -> np.random.Generator:
    """The Generator of bootstrap pool ``b`` at size ``participants`` (its resampling, then its draws)."""
    seq = np.random.SeedSequence(int(master_seed), spawn_key=(2**32 + BOOT_KEY, int(participants), int(b)))
    return np.random.default_rng(seq)


def resample_members(members: pd.DataFrame, rng: np.random.Generator) -> pd.DataFrame:
    """A bootstrap pool: within every (stratum, sequence) cell, as many people as the cell has, drawn with
    replacement (rows repeat; the member ids stay those of the pool's people)."""
    seq = members["sequence"].fillna(-1)
    parts = []
    for _, idx in members.groupby([members["stratum"], seq], sort=True).indices.items():
        parts.append(idx[rng.integers(0, len(idx), size=len(idx))])
    pick = np.sort(np.concatenate(parts)) if parts else np.zeros(0, dtype=np.intp)
    return members.iloc[pick].reset_index(drop=True)


@dataclass(frozen=True)
class PoolError:
    """Per test row and size: the pool's standard error of stage-2 power (``to_frame()``: :data:`COLUMNS`)."""

    frame: pd.DataFrame
    pools: int
    replicates: int

    def to_frame(self) -> pd.DataFrame:
        return self.frame.copy()


def pool_variance(powers: np.ndarray, replicates: int) -> float:
    """Between-pool variance of stage-2 power from B bootstrap powers of ``replicates`` draws each."""
    p = np.asarray(powers, dtype=float)
    if p.size < 2 or replicates < 2:
        return math.nan
    return max(float(p.var(ddof=1) - np.mean(p * (1 - p)) / (replicates - 1)), 0.0)


def pool_bootstrap(spec, pool, sizes: tuple[int, ...], pools: int, replicates: int, *,  # noqa: ANN001
                   draw=None) -> PoolError:  # noqa: ANN001
    """``pools`` bootstrap pools × ``replicates`` stage-2 replicates at each of ``sizes`` (see the module docs).

    ``draw(members, n, r, rng)`` → a replicate's rows frame (:data:`studyctl.power.replicate.ROW_COLUMNS`) from the
    members table given (default: :func:`studyctl.power.twostage.rows_from`, the plan's tests on the pool's rows).
    """
    from studyctl.power.twostage import Stage2

    stage2 = Stage2(spec, pool)
    out = []
    for n in sizes:
        per_pool = []
        for b in range(pools):
            rng = boot_rng(spec.seed, n, b)
            members = resample_members(pool.members, rng)
            frames = [(draw or stage2.rows_frame)(members, n, r, rng) for r in range(replicates)]
            rows = pd.concat(frames, ignore_index=True)
            per_pool.append(summarise(rows, (n,), replicates).frame.set_index(list(KEY))["power"])
        table = pd.concat(per_pool, axis=1).fillna(0.0)  # a row a bootstrap never produced: power 0 there
        for key, powers in table.iterrows():
            p = powers.to_numpy(dtype=float)
            var = pool_variance(p, replicates)
            out.append({"participants": n, **dict(zip(KEY, key, strict=True)), "boot_pools": pools,
                        "boot_replicates": replicates, "boot_power_mean": float(p.mean()),
                        "boot_power_sd": float(p.std(ddof=1)) if p.size > 1 else math.nan,
                        "pool_se": math.sqrt(var) if math.isfinite(var) else math.nan, "pool_people": pool.size})
    return PoolError(pd.DataFrame(out, columns=list(COLUMNS)), pools, replicates)
