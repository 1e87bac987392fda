"""The pool's own sampling error: a bootstrap of the pool, and a comparison whose SE includes it."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from power_testdata import PLAN, PROTOCOL, SEED

from studyctl.power import prepare_power
from studyctl.power.bootstrap import pool_bootstrap, pool_variance, resample_members
from studyctl.power.pool import build_pool
from studyctl.power.twostage import Stage2, compare


def test_pool_variance_removes_the_binomial_part():
    rng = np.random.default_rng(3)
    # one power for every pool: the spread of the estimates is all binomial, the pool's variance ~0
    same = rng.binomial(200, 0.4, size=400) / 200
    assert pool_variance(same, 200) == pytest.approx(0.0, abs=2e-4)
    # pools whose true power spreads with SD 0.08: the estimate finds it
    spread = rng.binomial(200, np.clip(rng.normal(0.5, 0.08, size=400), 0, 1)) / 200
    assert pool_variance(spread, 200) ** 0.5 == pytest.approx(0.08, abs=0.01)
    assert np.isnan(pool_variance(np.array([0.5]), 200))


def test_resampling_keeps_every_cell_size():
    members = pd.DataFrame({"member": [f"p{i}" for i in range(12)], "chunk": 0,
                            "stratum": ["a"] * 6 + ["b"] * 6, "sequence": [0, 1] * 6})
    boot = resample_members(members, np.random.default_rng(1))
    assert boot.groupby(["stratum", "sequence"]).size().tolist() == [3, 3, 3, 3]
    for (s, q), g in boot.groupby(["stratum", "sequence"]):
        own = set(members[(members["stratum"] == s) & (members["sequence"] == q)]["member"])
        assert set(g["member"]) <= own
    many = [resample_members(members, np.random.default_rng(k))["member"].nunique() for k in range(20)]
    assert min(many) < 12  # with replacement: someone repeats


@pytest.fixture(scope="module")
def small_pool(tmp_path_factory):
    spec = prepare_power(PROTOCOL, PLAN, sizes="4", replicates=3, seed=SEED)
    return spec, build_pool(spec, tmp_path_factory.mktemp("pools"), 12)


@pytest.mark.slow
def test_a_person_drawn_twice_is_two_participants(small_pool):
    """A replicate with a person twice equals the plan run on a table where the copy has its own code."""
    from studyctl.analysis.execute import hypothesis_rows
    from studyctl.analysis.shape import prepare
    from studyctl.analysis.table import MetricTable
    from studyctl.power.replicate import power_rows

    spec, pool = small_pool
    stage2 = Stage2(spec, pool)
    a, b, c = pool.members["member"].iloc[[0, 1, 6]]
    chosen = [a, b, c, a]
    got = stage2.rows(chosen)
    m = pool.metrics
    frame = pd.concat([m[m["participant"] == a], m[m["participant"] == b], m[m["participant"] == c],
                       m[m["participant"] == a].assign(participant=f"{a}~1")], ignore_index=True)
    want = power_rows(hypothesis_rows(spec.plan, prepare(spec.plan, MetricTable(frame=frame))))
    pd.testing.assert_frame_equal(pd.DataFrame(got), pd.DataFrame(want))
    # and the copy counts: three distinct people give other rows
    assert not pd.DataFrame(stage2.rows([a, b, c])).equals(pd.DataFrame(got))


@pytest.mark.slow
def test_pool_bootstrap_rows_and_compare_with_it(small_pool):
    spec, pool = small_pool
    boot = pool_bootstrap(spec, pool, (4,), 3, 4)
    f = boot.to_frame()
    assert not f.empty and (f["boot_pools"] == 3).all() and (f["pool_people"] == 12).all()
    assert ((f["pool_se"] >= 0) | f["pool_se"].isna()).all()
    again = pool_bootstrap(spec, pool, (4,), 3, 4).to_frame()
    pd.testing.assert_frame_equal(f, again)  # seeded


def test_compare_puts_the_pool_error_in_the_se():
    base = {"test_id": "t", "metric": "m", "split": "", "kind": "omnibus", "participants": 8, "groups": "condition"}
    two = pd.DataFrame([{**base, "power": 0.60, "replicates": 400, "power_ci_low": 0.55, "power_ci_high": 0.65}])
    ex = pd.DataFrame([{**base, "power": 0.50, "replicates": 100, "power_ci_low": 0.40, "power_ci_high": 0.60}])
    without = compare(two, ex, (8,))
    boot = pd.DataFrame([{**base, "role": "", "test": "", "parent": "", "pool_se": 0.08, "pool_people": 160,
                          "boot_pools": 20, "boot_replicates": 50}])
    with_pool = compare(two, ex, (8,), boot)
    binom = (100 * (0.6 * 0.4 / 400) ** 0.5) ** 2 + (100 * (0.25 / 100) ** 0.5) ** 2
    assert without.to_frame()["combined_se_pp"].iloc[0] == pytest.approx(binom ** 0.5)
    assert with_pool.to_frame()["combined_se_pp"].iloc[0] == pytest.approx((binom + 64) ** 0.5)
    s = with_pool.summary()
    assert s["power_error_pp"] == pytest.approx(10.0) and s["pool_se_pp_max"] == pytest.approx(8.0)
    assert s["chi2"] == pytest.approx(100 / (binom + 64))
    assert s["pool_people_for_2pp_se"] == 160 * 16  # (8 / 2)² times the pool
    assert np.isnan(without.summary()["pool_se_pp_max"])


def test_ctrl_c_in_the_pool_build_aborts_the_workers_and_writes_nothing(tmp_path, monkeypatch):
    """Ctrl-C while pool chunks run: the workers are killed at once (not waited for), no report is written."""
    from studyctl.workflows import power_two_stage as wf

    calls = []

    class Interrupted:
        class info:  # noqa: N801 - stands in for BackendInfo
            workers = 2

            @staticmethod
            def describe():
                return "fake"

        def map(self, *a, **k):
            raise KeyboardInterrupt

        def abort(self):
            calls.append("abort")

        def close(self):
            calls.append("close")

    monkeypatch.setattr(wf, "open_backend", lambda *a: Interrupted())
    spec = prepare_power(PROTOCOL, PLAN, sizes="4", replicates=3, seed=SEED)
    with pytest.raises(KeyboardInterrupt):
        wf.run_two_stage(spec, tmp_path / "out", pool_dir=tmp_path / "pools")
    assert calls == ["abort", "close"]
    assert not (tmp_path / "out").exists()


def test_curve_bench_picks_the_largest_complete_pool(tmp_path):
    import json
    import sqlite3

    from studyctl.bench.power_curve import _largest_pool
    from studyctl.power.pool import _SCHEMA

    assert _largest_pool(tmp_path, "p") is None
    for name, chunks in (("p-a", [0, 1]), ("p-b", [0, 1, 2]), ("p-c", [0, 2, 3, 4])):  # c has a hole: not a prefix
        with sqlite3.connect(tmp_path / f"{name}.sqlite") as c:
            c.executescript(_SCHEMA)
            c.execute("INSERT INTO meta VALUES ('key', ?)", (json.dumps({"chunk_size": 10, "seed": 1}),))
            c.executemany("INSERT INTO chunks VALUES (?, 1, 1, 'w')", [(k,) for k in chunks])
    path, chunks, size, _ = _largest_pool(tmp_path, "p")
    assert path.name == "p-b.sqlite" and chunks == 3 and size == 10


def test_curve_bench_sizes_follow_the_pool():
    """A pool below 20 × the default largest size gets five sizes it holds 20 × of (from the smallest default);
    one too small even for that keeps the default sizes, flagged as timing only."""
    from studyctl.bench.power_curve import _sizes

    default = (8, 12, 16, 20, 25)
    assert _sizes(default, 500) == (default, True)
    assert _sizes(default, 400) == ((8, 11, 14, 17, 20), True)
    assert _sizes(default, 320) == ((8, 10, 12, 14, 16), True)
    assert _sizes(default, 36) == (default, False)


def test_curve_bench_times_what_studyctl_power_runs_by_default(tmp_path, monkeypatch):
    """Seed 001's full-engine peer and stage 2 get the CLI's default cap (250 Hz), seed 000 its 50 Hz loops, and the
    JSON figures and notes say the rate (the library's prepare_power alone would run seed 001 at 1 kHz)."""
    import json
    import sqlite3
    from types import SimpleNamespace

    import studyctl.bench.power_curve as pc
    from studyctl.power.executor import SerialBackend
    from studyctl.power.pool import _SCHEMA

    for name in ("needle_insertion-x", "bio_inspired_palpation-x"):
        with sqlite3.connect(tmp_path / f"{name}.sqlite") as c:
            c.executescript(_SCHEMA)
            c.execute("INSERT INTO meta VALUES ('key', ?)", (json.dumps({"chunk_size": 12, "seed": 1}),))
            c.executemany("INSERT INTO chunks VALUES (?, 1, 1, 'w')", [(k,) for k in range(2)])
    seen = []
    monkeypatch.setattr(pc, "_stage2", lambda spec, *a: seen.append(("stage2", spec.sim_rate_hz)) or {
        "wall": 1.0, "cpu": 1.0, "busy": 1.0, "count": 1, "start_s": 0.0, "tasks": 1, "overhead_pct": 0.0})
    monkeypatch.setattr(SerialBackend, "run", lambda self, spec, tasks, keep: seen.append(
        ("exact", spec.sim_rate_hz, set(spec.loop_rates().values()))) or keep(SimpleNamespace(cpu_seconds=1.0)))
    figures, _, notes = pc.curve("needle_insertion", (4, 6, 8, 10, 12), 1, tmp_path, 0)
    assert seen == [("stage2", 250.0), ("exact", 250.0, {250.0})]
    assert figures["loop_rate_hz_needle"] == 250.0 and "capped at 250 Hz" in notes[0]
    seen.clear()
    figures, _, notes = pc.curve("bio_inspired_palpation", (8, 12, 16, 20, 25), 1, tmp_path, 0)
    assert seen == [("stage2", None), ("exact", None, {50.0})]
    assert figures["loop_rate_hz_bio"] == 50.0 and "(the protocol's rates)" in notes[0]
