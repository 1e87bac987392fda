"""The demo pipeline end to end on a small cohort: virtual participants → database → analysis → report."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from studyctl.errors import ConfigError
from studyctl.workflows.demo import MARKER, run_demo


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "reports"
    events = []
    result = run_demo(out, seed=11, studies=[("bio_inspired_palpation", 2)], workers=2, on_event=events.append)
    return result, events


@pytest.mark.slow
def test_small_demo_writes_a_report_from_simulated_data(demo):
    result, events = demo
    (run,) = result.studies
    assert run.ok, run.error
    assert run.trials_completed == 8  # 2 participants × 4 conditions, all through the engine
    folder = result.out_dir / "bio_inspired_palpation"
    assert (folder / MARKER).is_file() and (folder / "workspace" / "study.db").is_file()
    assert (folder / "report.html").is_file() and (folder / "figures" / "fig4_controller_outputs.png").is_file()
    tests = pd.read_csv(folder / "tests.csv")
    assert set(tests["test_id"]) >= {"novice_vs_expert", "control_algorithm", "tumour_class", "within_subject"}
    units = pd.read_csv(folder / "units.csv")
    assert set(units["participant"].dropna()) and units["participant"].nunique() == 2
    assert "bio_inspired_palpation" in result.index.read_text()
    stages = [e[1] for e in events]
    assert stages[0] == "simulate" and stages[-1] == "done" and "analyse" in stages
    saved = json.loads((result.out_dir / "demo.json").read_text())
    assert saved[0]["study"] == "bio_inspired_palpation" and saved[0]["trials_completed"] == 8


@pytest.mark.slow
def test_demo_refuses_to_clear_a_folder_it_did_not_make(tmp_path):
    precious = tmp_path / "reports" / "bio_inspired_palpation"
    precious.mkdir(parents=True)
    (precious / "notes.txt").write_text("mine")
    result = run_demo(tmp_path / "reports", studies=[("bio_inspired_palpation", 1)], workers=1)
    (run,) = result.studies
    assert not run.ok and "is not empty and was not made by studyctl demo" in run.error
    assert (precious / "notes.txt").read_text() == "mine"


def test_demo_output_must_be_writable(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ConfigError, match="cannot write the report to"):
        run_demo(blocker / "reports", studies=[("bio_inspired_palpation", 1)], workers=1)


def test_every_default_loop_rate_is_the_one_in_engine_loop_rates():
    """demo (CLI and library), calibrate and bench tick read one constant; no command keeps a literal of its own."""
    import inspect

    import typer

    from studyctl.cli import analysis, calibrate
    from studyctl.engine.loop_rates import SIM_RATE_HZ

    def cli_default(register, command: str) -> float:
        app = typer.Typer()
        register(app)
        click = typer.main.get_command(app)
        cmd = click.commands[command] if hasattr(click, "commands") else click
        return next(p.default for p in cmd.params if p.name == "sim_rate_hz")

    assert cli_default(analysis.register_sim, "demo") == SIM_RATE_HZ
    assert cli_default(calibrate.register, "calibrate") == SIM_RATE_HZ
    assert inspect.signature(run_demo).parameters["sim_rate_hz"].default == SIM_RATE_HZ
    for module in (analysis, calibrate):
        assert "250.0" not in inspect.getsource(module)


@pytest.mark.slow
def test_the_index_says_at_which_loop_rate_the_sessions_ran(demo):
    result, _ = demo
    assert result.sim_rate_hz == 250.0
    assert "ran at 250 Hz" in result.index.read_text()


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_a_bad_loop_rate_is_refused_before_anything_is_written(tmp_path, bad):
    from studyctl.errors import UsageError

    with pytest.raises(UsageError, match="--sim-rate-hz .* must be a positive number"):
        run_demo(tmp_path / "reports", studies=[("bio_inspired_palpation", 1)], sim_rate_hz=bad)
    assert not (tmp_path / "reports").exists()


@pytest.mark.slow
def test_the_index_shows_each_studys_own_time_and_its_agreement_with_the_paper(demo):
    result, _ = demo
    (run,) = result.studies
    page = result.index.read_text()
    # The study's own session time is not the demo clock at which its report was ready.
    assert 0 < run.simulate_s and f"{run.simulate_s:.1f} s" in page and f"{run.total_s:.1f} s" in page
    assert "session time (sum)" in page and "ready after" in page
    assert run.agreement.startswith(tuple(f"{k}/" for k in range(40))) and run.agreement in page.replace("&#39;", "'")
    assert run.population and run.population.split(" (")[0] in page
    assert json.loads((result.out_dir / "demo.json").read_text())[0]["agreement"] == run.agreement


@pytest.mark.slow
def test_a_studys_report_goes_ahead_of_other_studies_waiting_sessions(tmp_path):
    # bio-inspired (costlier per person) is handed out first: its one session ends while most of the data-driven
    # sessions still wait, and its report must then run before them, not after the last of them (the pool's own
    # first-in-first-out queue put every report behind every session)
    events = []
    studies = [("data_driven_palpation", 16), ("bio_inspired_palpation", 1)]
    result = run_demo(tmp_path / "reports", seed=3, studies=studies, workers=2, on_event=events.append)
    assert result.ok, [s.error for s in result.studies]
    bio_done = events.index(("bio_inspired_palpation", "done", 1, 1, "report written"))
    last_session = max(i for i, e in enumerate(events) if e[0] == "data_driven_palpation" and e[1] == "simulate")
    assert bio_done < last_session, events
    assert [s.study for s in result.studies] == ["data_driven_palpation", "bio_inspired_palpation"]


@pytest.mark.slow
def test_bench_demo_counts_the_workers_cpu_beside_the_wall_time(monkeypatch):
    import os
    import time

    import studyctl.workflows.demo as demo_module
    from studyctl.bench import demo as bench_demo

    monkeypatch.setattr(demo_module, "REFERENCE_STUDIES", (("data_driven_palpation", 2),))
    own0 = time.process_time()
    result = bench_demo.run()
    own = time.process_time() - own0
    f = result.figures
    assert f["cpu_s"] > own  # the sessions and the report ran in the pool's worker processes, and are counted
    workers = os.cpu_count() or 1  # the demo's default pool
    assert 0.0 < f["parallel_efficiency"] <= 1.0 + own / f["demo_s"]  # the main process may add its own CPU
    assert f["parallel_efficiency"] == pytest.approx(f["cpu_s"] / (workers * f["demo_s"]))


@pytest.mark.slow
def test_a_script_without_a_main_guard_is_told_and_its_workers_touch_nothing(tmp_path):
    # spawned workers import the script; without the guard each would run the demo again into the same folder (and
    # clear the parent's): they refuse at once, and the parent's studies name the likely cause
    import subprocess
    import sys

    script = tmp_path / "noguard.py"
    script.write_text(
        "from studyctl.workflows.demo import run_demo\n"
        "r = run_demo('reports', studies=[('data_driven_palpation', 2)], workers=2)\n"
        "print('ERROR', r.studies[0].error.splitlines()[0])\n"
    )
    out = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert "run_demo was called while one of its worker processes was starting" in out.stderr
    (line,) = [x for x in out.stdout.splitlines() if x.startswith("ERROR")]
    assert "a worker process ended abruptly" in line and '`if __name__ == "__main__":` guard' in line
