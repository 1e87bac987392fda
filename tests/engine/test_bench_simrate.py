"""The loop-rate benchmark runs end to end (quick) and compares like with like."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from studyctl.bench.simrate import _compare, compare_metrics
from studyctl.cli.app import main


def _frame(found: list[float], times: list[float]) -> pd.DataFrame:
    rows = [{"participant": "P1", "condition": c, "metric": "completion_time", "level": None, "value": t,
             "denominator": None} for c, t in zip(("a", "b"), times, strict=True)]
    rows += [{"participant": "P1", "condition": "a", "metric": "sensitivity", "level": lvl, "value": v,
              "denominator": 1.0} for lvl, v in zip("ABC", found, strict=True)]
    return pd.DataFrame(rows)


def test_compare_counts_gains_losses_and_duration_bias():
    ref = _frame([1.0, 0.0, 1.0], [100.0, 50.0])
    other = _frame([1.0, 1.0, 0.0], [110.0, 50.0])
    got = _compare(ref, other, "completion_time")
    assert got["found_gained"] == 1 and got["found_lost"] == 1 and got["found_agree"] == 1 / 3
    assert got["time_rel_err"] == 0.05 and got["time_rel_bias"] == 0.05  # (+10 % and 0 %) / 2
    assert got["se_diff_pp"] == 0.0


def _needle(values: dict[str, list[float]], participant: str = "P1") -> pd.DataFrame:
    rows = [{"participant": participant, "condition": "BL", "repetition": float(r), "metric": m, "level": None,
             "value": v} for m, vs in values.items() for r, v in enumerate(vs, start=1)]
    return pd.DataFrame(rows)


def test_needle_metrics_are_compared_trial_by_trial_with_their_bias_and_its_error():
    ref = pd.concat([_needle({"targeting_error": [1.0, 2.0, 3.0], "scans": [4.0, 4.0, 2.0]}),
                     _needle({"targeting_error": [1.0, 1.0, 1.0], "scans": [3.0, 3.0, 3.0]}, "P2")])
    other = pd.concat([_needle({"targeting_error": [1.5, 2.5, 2.0], "scans": [4.0, 4.0, 2.0]}).iloc[:-1],
                       _needle({"targeting_error": [1.5, 1.5, 1.5], "scans": [3.0, 3.0, 3.0]}, "P2")])
    got = compare_metrics(ref, other, ("targeting_error", "scans"))  # one scans trial of P1 missing
    assert got["trials_unpaired"] == 1.0
    d = pd.Series([0.5, 0.5, -1.0, 0.5, 0.5, 0.5])
    assert got["targeting_error_abs"] == pytest.approx(d.abs().mean()) and got["targeting_error_bias"] == 0.25
    assert got["targeting_error_rel"] == pytest.approx(d.abs().mean() / 1.5)
    assert got["targeting_error_bias_se_trials"] == pytest.approx(d.std() / 6 ** 0.5)
    # participants as the units: P1's differences average 0, P2's 0.5; equal sizes -> SD of those means / sqrt(2)
    assert got["targeting_error_bias_se"] == pytest.approx(pd.Series([0.0, 0.5]).std() / 2 ** 0.5)
    assert got["scans_abs"] == 0.0 and got["scans_bias"] == 0.0 and got["scans_bias_se"] == 0.0


def test_a_bias_carried_by_one_person_is_not_taken_for_many_independent_trials():
    """Ten people, one of whom is 1 mm off in all 15 trials: trial-level SE would call it z ~ 3.7; with the
    participant as the unit it is z 1 (one person of ten)."""
    ref = pd.concat([_needle({"targeting_error": [1.0] * 15}, f"P{i}") for i in range(10)])
    other = pd.concat([_needle({"targeting_error": [2.0 if i == 0 else 1.0] * 15}, f"P{i}") for i in range(10)])
    got = compare_metrics(ref, other, ("targeting_error",))
    assert got["targeting_error_bias"] == pytest.approx(0.1)
    assert got["targeting_error_bias"] / got["targeting_error_bias_se_trials"] > 3.5
    assert got["targeting_error_bias"] / got["targeting_error_bias_se"] == pytest.approx(1.0)


@pytest.mark.slow
def test_quick_run_prints_speed_and_error(capsys):
    assert main(["bench", "simrate", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    fig = out["figures"]
    assert fig["speedup_250_data_driven_palpation"] > 1.0
    assert 0.0 <= fig["found_agree_250_data_driven_palpation"] <= 1.0
    assert [r["rate_hz"] for r in out["tables"]["rates"]] == [1000.0, 250.0]


def test_the_yardstick_runs_the_same_people_on_other_session_seeds(tmp_path):
    """The reseeded 1 kHz cohort must hold each person (traits of the default session seed) and change only the
    session's random streams; drawing the traits from the new seed would compare other people with them."""
    import json
    import sqlite3
    from pathlib import Path

    from studyctl.bench.simrate import _run_reseeded
    from studyctl.engine.seeding import person_traits, session_seed
    from studyctl.populations import load_population_file
    from studyctl.store.workspace import open_study
    from studyctl.workflows.simulate import create_cohort, run_participant

    tests = Path(__file__).parent.parent
    population = load_population_file(tests / "populations" / "data" / "palpator_small.yaml")
    runs = {}
    for reseed in (0, 1):
        cohort = create_cohort(tests / "power" / "data" / "mini_palpation.yaml", 2, 31, tmp_path / f"r{reseed}",
                               population=population)
        with open_study(cohort.db, cohort.workspace, cohort.study) as opened:
            for code in cohort.codes:
                if reseed:
                    _run_reseeded(opened.store, cohort, code, reseed)
                else:
                    run_participant(cohort, code, store=opened.store)
        con = sqlite3.connect(cohort.database)
        runs[reseed] = {code: (seed, json.loads(payload)) for code, seed, payload in con.execute(
            "select p.code, s.seed, e.payload from event e join session s on s.id = e.session_id join participant p"
            " on p.id = s.participant_id where e.kind = 'population'")}
        con.close()
    assert runs[0].keys() == runs[1].keys() and len(runs[0]) == 2
    for code, (seed, record) in runs[1].items():
        default_seed, default_record = runs[0][code]
        assert default_seed == session_seed(31, code) and seed == default_seed + 1
        assert record["traits"] == default_record["traits"]  # the same person ...
        assert record["traits"] == pytest.approx(person_traits(population, default_seed, record["stratum"]))
        # ... not the person the new seed would draw
        assert record["traits"] != pytest.approx(person_traits(population, seed, record["stratum"]))
