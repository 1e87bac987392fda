"""A stage-2 replicate's tests from the pool's precomputed units equal the plan's tests on the replicate's own
table (the shipped seed-000 plan: rank-sum, Kruskal-Wallis + multcompare, Friedman + signed-rank, ART, LMM)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from studyctl.analysis import load_plan, run_plan
from studyctl.analysis.execute import hypothesis_rows, is_hypothesis_entry
from studyctl.analysis.results import rows_frame
from studyctl.analysis.shape import prepare
from studyctl.analysis.table import COLUMNS, MetricTable
from studyctl.power.units import PoolUnits, replicate_rows

CONDITIONS = ("no_feedback", "piecewise", "linear", "bio_inspired")
CONTINUOUS = {"accuracy": 0.6, "mean_force": 2.0, "completion_time": 90.0, "contact_time": 8.0}


def _pool(rng: np.random.Generator, people: int) -> pd.DataFrame:
    """Metric rows shaped like a seed-000 pool's: 1–2 trials per condition, detection per tumour class, a few
    undefined values and one person who skipped a condition (unbalanced designs take the iterative paths)."""
    rows = []
    for p in range(people):
        member = f"c{p // 12:05d}-BIP-V{p:04d}"
        group = "expert" if p % 3 == 0 else "novice"
        shift = rng.normal(0, 0.3)
        for c, cond in enumerate(CONDITIONS):
            if p == 5 and cond == "linear":
                continue
            for trial in range(1 + (p + c) % 2):
                for metric, base in CONTINUOUS.items():
                    value = base * (1 + shift + 0.15 * c + rng.normal(0, 0.3))
                    if metric == "accuracy":
                        value = float(np.clip(round(value * 3) / 3, 0, 1))
                    if p == 7 and metric == "contact_time" and trial == 0:
                        value = np.nan
                    rows.append((member, group, cond, 4 * c + trial + 1, trial + 1, metric, None, value, np.nan))
                for level in ("hard", "medium", "soft"):
                    hit = float(rng.random() < 0.4 + 0.15 * c)
                    rows.append((member, group, cond, 4 * c + trial + 1, trial + 1, "detection", level, hit, 1.0))
    return pd.DataFrame(rows, columns=list(COLUMNS))


@pytest.fixture(scope="module")
def plan():
    return load_plan("bio_inspired_palpation")


@pytest.fixture(scope="module")
def pool(plan):
    metrics = _pool(np.random.default_rng(20261125), 36)
    return metrics, dict(tuple(metrics.groupby("participant", sort=False))), PoolUnits(plan, metrics, "t")


@pytest.mark.slow
@pytest.mark.parametrize(("size", "seed"), [(8, 1), (12, 2), (17, 3)])
def test_pool_units_give_the_tests_of_the_replicate_table(plan, pool, size, seed):
    metrics, by_member, units = pool
    members = list(by_member)
    chosen = [members[i] for i in np.random.default_rng(seed).choice(len(members), size, replace=False)]
    table = MetricTable(frame=pd.concat([by_member[m] for m in chosen], ignore_index=True), source="t", study="t")
    direct = rows_frame(hypothesis_rows(plan, prepare(plan, table)))
    drawn = rows_frame(replicate_rows(units, chosen, by_member))
    assert len(direct) > 60 and set(direct["test"]) >= {"rank_sum", "kruskal_wallis", "friedman", "art_anova",
                                                           "mixed_model"}
    pd.testing.assert_frame_equal(drawn, direct)
    # the same rows run_plan gives for the hypothesis entries (only descriptive tables and intervals are left out)
    full = run_plan(plan, table).to_frame()
    keep = [e.id for e in plan.tests if is_hypothesis_entry(e)]
    # (full's "significant" column is object-typed: its interval rows hold None)
    pd.testing.assert_frame_equal(direct, full[full["test_id"].isin(keep)].reset_index(drop=True), check_dtype=False)
    assert set(full["test_id"]) - set(keep) == {"detection_probability"}  # its Wilson intervals (summary: a table)


@pytest.mark.slow
def test_other_people_change_the_rows(plan, pool):
    """The comparison above can fail: a replicate of other people gives other rows."""
    _, by_member, units = pool
    members = list(by_member)
    a = rows_frame(replicate_rows(units, members[:8], by_member))
    b = rows_frame(replicate_rows(units, members[1:9], by_member))
    assert not a["p"].equals(b["p"])


@pytest.mark.slow
def test_power_rows_read_straight_from_the_rows_are_the_frame_path(plan, pool):
    """Power rows are read straight from the test rows; they are the rows frame's values (the path full-engine
    replicates took before, kept here as the reference): NaN where the frame has NaN, "" for missing text,
    significance as bool."""
    from studyctl.power.replicate import power_rows

    _, by_member, units = pool
    members = list(by_member)
    for seed in range(4):
        chosen = [members[i] for i in np.random.default_rng(seed).choice(len(members), 8 + seed, replace=False)]
        rows = replicate_rows(units, chosen, by_member)
        direct, framed = power_rows(rows), _framed(rows_frame(rows))
        assert len(direct) > 60
        pd.testing.assert_frame_equal(pd.DataFrame(direct), pd.DataFrame(framed))
        assert all(type(a) is type(b) for r, s in zip(direct, framed, strict=True) for a, b in zip(r, s, strict=True))


def _framed(frame: pd.DataFrame) -> tuple[tuple, ...]:
    """Power rows through a DataFrame of the test rows (the reference for :func:`power_rows`)."""
    from studyctl.power.replicate import _KEEP
    from studyctl.power.spec import TEST_KINDS

    def missing(v: object) -> bool:
        return v is None or (isinstance(v, float) and math.isnan(v))

    out = []
    for rec in frame[frame["kind"].isin(TEST_KINDS)][list(_KEEP)].itertuples(index=False, name=None):
        row = [v.item() if hasattr(v, "item") else v for v in rec]
        i = _KEEP.index("significant")
        row[i] = None if missing(row[i]) else bool(row[i])
        for col in ("parent", "effect_size_name", "split", "groups", "metric", "role", "test"):
            i = _KEEP.index(col)
            row[i] = "" if missing(row[i]) else str(row[i])
        out.append(tuple(row))
    return tuple(out)
