"""Replicates through the real engine, the power table, resumable runs and the report folder."""

from __future__ import annotations

import json
import sqlite3
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from power_testdata import REPLICATES, SIZES

from studyctl.power import Population, simulate_replicate, summarise
from studyctl.power.replicate import ROW_COLUMNS
from studyctl.power.summary import COLUMNS
from studyctl.stats import wilson_interval
from studyctl.workflows.power import run_power


@pytest.mark.slow
def test_replicate_runs_whole_sessions_and_the_plan(serial_run):
    reps = serial_run.replicates
    assert len(reps) == len(SIZES) * REPLICATES
    # every participant's whole session ran: 2 conditions x 1 repetition each
    assert (reps["sessions_completed"] == reps["participants"]).all()
    assert (reps["trials_completed"] == 2 * reps["participants"]).all()
    assert (reps["trials_not_completed"] == 0).all()


def test_replicate_is_a_pure_function_of_its_arguments(mini_spec, serial_run):
    again = simulate_replicate(mini_spec, 2, 1).to_frame()
    assert list(again.columns) == list(ROW_COLUMNS)
    stored = pd.read_sql_query("SELECT * FROM rows WHERE participants = 2 AND replicate = 1",
                               sqlite3.connect(serial_run.files["results"]))
    assert np.allclose(again["p"].to_numpy(float), stored["p"].to_numpy(float), equal_nan=True)
    assert np.allclose(again["effect_size"].to_numpy(float), stored["effect_size"].to_numpy(float), equal_nan=True)
    assert list(again["test_id"]) == list(stored["test_id"])
    assert set(again["kind"]) <= {"omnibus", "two_sample", "pairwise", "posthoc"}


@pytest.mark.slow
def test_population_knob_reaches_the_virtual_participants(mini_spec):
    """Numbing the palpator's feel (thresholds above anything the actuators give) in the linear condition
    changes what the engine records there, and only there."""
    tables = []
    simulate_replicate(mini_spec, 2, 0, on_metrics=tables.append)
    numb = Population(condition_effects={"linear": {"balloon_threshold_psi": 19.0, "vibration_threshold_ms2": 19.0}})
    simulate_replicate(replace(mini_spec, population=numb), 2, 0, on_metrics=tables.append)
    base, changed = (t.to_frame().set_index(["participant", "condition", "metric"])["value"] for t in tables)
    assert base.xs("no_feedback", level="condition").equals(changed.xs("no_feedback", level="condition"))
    assert not base.xs("linear", level="condition").equals(changed.xs("linear", level="condition"))


def test_power_table_counts_significant_rows_with_wilson_intervals(serial_run):
    frame = serial_run.to_frame()
    assert list(frame.columns) == list(COLUMNS)
    reps = serial_run.replicates
    rows = pd.read_sql_query("SELECT * FROM rows", sqlite3.connect(serial_run.files["results"]))
    for r in frame.itertuples(index=False):
        sel = rows[(rows["participants"] == r.participants) & (rows["test_id"] == r.test_id)
                   & (rows["metric"] == r.metric)]
        k = int((sel["significant"] == 1).sum())
        n = int((reps["participants"] == r.participants).sum())
        ci = wilson_interval(k, n)
        assert (r.significant, r.replicates) == (k, n)
        assert (r.power, r.power_ci_low, r.power_ci_high) == pytest.approx((ci.estimate, ci.lower, ci.upper))


def test_summary_rules_on_synthetic_rows():
    def row(n, r, kind, groups, p, sig, eff, status="ok", parent=""):
        return (n, r, "t", "paper", kind, "kruskal_wallis", "time", "", groups, parent, p, np.nan, sig,
                "epsilon_squared", eff, status)

    data = [row(8, 0, "omnibus", "a, b, c", 0.01, True, 0.4), row(8, 1, "omnibus", "a, b, c", 0.2, False, 0.1),
            row(8, 2, "omnibus", "a, b", np.nan, None, np.nan, status="not_computed"),
            row(8, 3, "omnibus", "a, b, c", 0.03, True, 0.3),
            row(8, 0, "posthoc", "a vs b", 0.02, True, 1.0, parent="t"),
            row(8, 3, "posthoc", "a vs b", 0.2, False, 0.5, parent="t")]
    rows = pd.DataFrame(data, columns=list(ROW_COLUMNS))
    table = summarise(rows, (8,), 4).to_frame()
    omni = table[table["kind"] == "omnibus"].iloc[0]
    assert omni["groups"] == "a, b, c"  # the computed rows' levels, not the incomplete replicate's
    assert (omni["significant"], omni["replicates"], omni["computed"]) == (2, 4, 3)
    assert omni["effect_median"] == pytest.approx(0.3) and omni["effect_q025"] == pytest.approx(0.11)
    post = table[table["kind"] == "posthoc"].iloc[0]
    assert (post["significant"], post["replicates"], post["power"]) == (1, 4, 0.25)  # absent = not significant


def test_report_folder(serial_run):
    files = serial_run.files
    for key in ("table", "figure", "population", "replicates", "settings", "results"):
        assert files[key].is_file(), key
    assert files["figure"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = pd.read_csv(files["table"])
    assert list(table.columns) == list(COLUMNS) and set(table["participants"]) == set(SIZES)
    settings = json.loads(files["settings"].read_text(encoding="utf-8"))
    assert settings["participants"] == list(SIZES) and settings["replicates"] == REPLICATES


@pytest.mark.slow
def test_interrupted_run_continues_and_matches(mini_spec, serial_run, tmp_path):
    class Stop(Exception):
        pass

    def stop_after_one(done, total, result):
        if result is not None and done == 1:
            raise Stop

    small = replace(mini_spec, sizes=(2,))
    with pytest.raises(Stop):
        run_power(small, tmp_path, workers=0, on_progress=stop_after_one, figure=False)
    seen = []
    resumed = run_power(small, tmp_path, workers=0, figure=False, on_progress=lambda d, t, r: seen.append(d))
    assert (resumed.reused, resumed.ran) == (1, REPLICATES - 1)
    assert seen[0] == 1
    reference = serial_run.to_frame()
    pd.testing.assert_frame_equal(resumed.to_frame(), reference[reference["participants"] == 2].reset_index(drop=True))
    again = run_power(small, tmp_path, workers=0, figure=False)
    assert (again.ran, again.reused) == (0, REPLICATES)
    # fewer replicates than stored: only the requested ones count
    fewer = run_power(replace(small, replicates=1), tmp_path, workers=0, figure=False)
    assert set(fewer.to_frame()["replicates"]) == {1}


def test_figure_draws_one_panel_per_test(serial_run):
    from studyctl.report.power_figures import power_curve_figure

    fig = power_curve_figure(serial_run.to_frame(), alpha=0.05, replicates=REPLICATES,
                             population=Population(condition_effects={"linear": {"balloon_weber": 0.1}}))
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == serial_run.to_frame()["test_id"].nunique()
    assert "linear: balloon_weber +0.1" in fig.get_supxlabel() if hasattr(fig, "get_supxlabel") else True


def test_memory_cap_stops_a_replicate_with_a_clear_error(mini_spec):
    from studyctl.power.replicate import WorkerMemoryError

    tiny = replace(mini_spec, memory_limit=1024)  # below any Python process: refused before the first session
    with pytest.raises(WorkerMemoryError, match=r"over the cap of 0 MiB per worker; raise --memory-limit"):
        simulate_replicate(tiny, 2, 0)
