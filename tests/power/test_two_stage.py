"""The two-stage design: a stored, reusable pool simulated through the full engine; replicates drawn from it."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from power_testdata import PLAN, PROTOCOL, SEED, run_power_cli

from studyctl.analysis import run_plan
from studyctl.analysis.table import MetricTable
from studyctl.errors import UsageError
from studyctl.power import prepare_power
from studyctl.power.pool import build_pool, check_pool_size, chunk_size
from studyctl.power.replicate import power_rows, simulate_study
from studyctl.power.seeds import pool_seeds
from studyctl.power.twostage import Stage2, compare, composition, draw_members
from studyctl.protocol import load_protocol


@pytest.fixture(scope="module")
def spec12():
    return prepare_power(PROTOCOL, PLAN, sizes="12", replicates=3, seed=SEED)


@pytest.fixture(scope="module")
def one_chunk_pool(spec12, tmp_path_factory):
    """A pool of exactly one chunk (12 people: whole Williams blocks in both strata)."""
    folder = tmp_path_factory.mktemp("pools")
    return folder, build_pool(spec12, folder, 12)


def test_pool_too_small_is_refused():
    assert check_pool_size(None, (4, 8)) == 160
    with pytest.raises(UsageError, match=r"--pool 100: .*\(20 × 8 = 160\).*use --pool 160"):
        check_pool_size(100, (4, 8))


def test_chunk_completes_the_blocks():
    assert chunk_size(load_protocol(PROTOCOL)) == 12  # 2 sequences × 2 strata, at least 10 people


@pytest.mark.slow
def test_pool_rows_are_the_full_engine_study(spec12, one_chunk_pool):
    """Drawing all 12 people of a one-chunk pool gives exactly the plan's result on that simulated study."""
    _, pool = one_chunk_pool
    assert pool.size == 12 and pool.built_now == 1
    assert pool.members.groupby(["stratum", "sequence"]).size().tolist() == [3, 3, 3, 3]
    study = simulate_study(spec12, 12, pool_seeds(SEED, 12, 0), "again", "test")
    direct = power_rows(run_plan(spec12.plan, study.table).rows)
    drawn = Stage2(spec12, pool).replicate(12, 0).rows
    pd.testing.assert_frame_equal(pd.DataFrame(drawn), pd.DataFrame(direct))
    # and a table from other people changes the answer (the comparison above can fail)
    other = study.table.frame[study.table.frame["participant"] != study.table.frame["participant"].iloc[0]]
    fewer = pd.DataFrame(power_rows(run_plan(spec12.plan, MetricTable(frame=other)).rows))
    assert not fewer.equals(pd.DataFrame(direct))


def test_pool_is_stored_and_reused_by_key(spec12, one_chunk_pool):
    folder, first = one_chunk_pool
    again = build_pool(spec12, folder, 12)
    assert again.built_now == 0 and again.path == first.path
    pd.testing.assert_frame_equal(again.metrics, first.metrics)
    other_seed = dataclasses.replace(spec12, seed=SEED + 1)
    from studyctl.power.pool import PoolFile, pool_key

    assert PoolFile.open(folder, pool_key(other_seed, 12), "mini").path != first.path


def test_draws_respect_strata_and_sequences(spec12, one_chunk_pool):
    _, pool = one_chunk_pool
    protocol = load_protocol(PROTOCOL)
    cells = composition(protocol, SEED, 4, 0)
    assert cells == {("novice", 0): 1, ("novice", 1): 1, ("expert", 0): 1, ("expert", 1): 1}
    picked = draw_members(pool, cells, np.random.default_rng(1))
    got = pool.members.set_index("member").loc[picked]
    assert sorted(zip(got["stratum"], got["sequence"], strict=True)) == sorted(cells)
    assert len(set(picked)) == 4
    with pytest.raises(UsageError, match="use a larger --pool"):
        draw_members(pool, {("novice", 0): 4}, np.random.default_rng(1))
    a, b = Stage2(spec12, pool).replicate(4, 7), Stage2(spec12, pool).replicate(4, 7)
    pd.testing.assert_frame_equal(pd.DataFrame(a.rows), pd.DataFrame(b.rows))


def test_compare_states_difference_and_mc_error():
    base = {"test_id": "t", "metric": "m", "split": "", "kind": "omnibus", "participants": 8, "groups": "condition"}
    term = {**base, "groups": "group"}  # another term of the same model: compared with its own counterpart only
    two = pd.DataFrame([{**base, "power": 0.80, "replicates": 400, "power_ci_low": 0.76, "power_ci_high": 0.84},
                        {**term, "power": 0.10, "replicates": 400, "power_ci_low": 0.07, "power_ci_high": 0.13}])
    ex = pd.DataFrame([{**base, "power": 0.75, "replicates": 100, "power_ci_low": 0.66, "power_ci_high": 0.82},
                       {**term, "power": 0.12, "replicates": 100, "power_ci_low": 0.07, "power_ci_high": 0.2}])
    err = compare(two, ex, (8,))
    assert len(err.to_frame()) == 2
    row = err.to_frame().set_index("groups").loc["condition"]
    assert row["diff_pp"] == pytest.approx(5.0)
    assert row["mc_se_exact_pp"] == pytest.approx(100 * (0.75 * 0.25 / 100) ** 0.5)
    assert row["mc_se_two_stage_pp"] == pytest.approx(2.0)
    assert err.summary()["power_error_pp"] == pytest.approx(5.0)


@pytest.mark.slow
def test_cli_two_stage_json(tmp_path, capsys):
    code, stdout, stderr = run_power_cli([PROTOCOL, "--plan", PLAN, "--participants", "4", "--replicates", "10",
                                          "--seed", SEED, "--workers", "0", "--out", tmp_path / "out", "--two-stage",
                                          "--pool-dir", tmp_path / "pools", "--check-replicates", "2", "--json"],
                                         capsys)
    assert code == 0, stderr
    doc = json.loads(stdout)
    assert doc["design"] == "two-stage" and doc["pool"]["people"] >= 80
    assert doc["power_error"]["checked_sizes"] == [4] and doc["power_error"]["exact_replicates"] == 2
    assert doc["power_error"]["two_stage_replicates"] == 10
    assert (tmp_path / "out" / "power_error.csv").is_file()


def test_batches_are_runs_of_one_size():
    from studyctl.power.twostage import batches

    todo = [(4, 0), (4, 1), (4, 2), (4, 5), (8, 0), (8, 1)]
    assert batches(todo, 2) == [(4, 0, 2), (4, 2, 3), (4, 5, 6), (8, 0, 2)]
    assert sum(b - a for _, a, b in batches(todo, 50)) == len(todo)


@pytest.mark.slow
def test_a_batch_loads_the_pool_file_and_draws_the_same_replicates(spec12, one_chunk_pool):
    from studyctl.power.twostage import draw_batch

    _, pool = one_chunk_pool
    got = draw_batch(spec12, str(pool.path), 1, pool.chunk_size, 4, 2, 5)
    assert [r.replicate for r in got] == [2, 3, 4]
    stage2 = Stage2(spec12, pool)
    for r in got:
        pd.testing.assert_frame_equal(pd.DataFrame(r.rows), pd.DataFrame(stage2.replicate(4, r.replicate).rows))


def test_pool_key_follows_the_simulation_code(spec12, monkeypatch):
    """A pool is never grown across a code change: the simulation code's digest is part of its key."""
    from studyctl.power import pool as pool_mod

    digest = pool_mod.simulation_code_digest()
    assert len(digest) == 64 and digest == pool_mod.simulation_code_digest()
    before = pool_mod.pool_key(spec12, 12)
    monkeypatch.setattr(pool_mod, "simulation_code_digest", lambda: "0" * 64)
    assert pool_mod.pool_key(spec12, 12) != before


def test_pool_key_leaves_out_the_modules_that_only_test_stored_rows():
    """Stage 2's statistics (the plan's execution, shaping, procedures) can change without invalidating a stored
    pool; the modules that simulate and measure people (engine, metrics) stay in its key."""
    from studyctl.power import pool as pool_mod

    files = {p.as_posix() for p in pool_mod.simulation_files()}
    for kept in ("analysis/metrics.py", "analysis/trials.py", "engine/api.py", "power/replicate.py",
                 "power/pool.py"):
        assert kept in files
    for left in ("analysis/execute.py", "analysis/shape.py", "analysis/procedures/models.py", "stats/models.py",
                 "power/twostage.py", "power/units.py"):
        assert left not in files
    # Population files are keyed by the spec's own population digest, not by the code digest: a refit of another
    # protocol's population keeps this pool; the loader that turns a file into traits stays in.
    assert "populations/loader.py" in files
    assert not [f for f in files if f.startswith("populations/") and not f.endswith(".py")]


def test_the_pools_own_population_file_is_in_its_key():
    """Leaving population files out of the code digest is safe only because the pool's own population is keyed."""
    from studyctl.power import pool as pool_mod

    spec = prepare_power("bio_inspired_palpation", "bio_inspired_palpation", sizes="8", replicates=1, seed=SEED)
    assert spec.traits is not None and spec.traits.sha256
    assert pool_mod.pool_key(spec, 8)["traits_sha256"] == spec.traits.sha256
