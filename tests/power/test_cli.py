"""``studyctl power``: help, one-line errors for bad input (exit code, nothing written), a serial run."""

from __future__ import annotations

import socket

import pandas as pd
import pytest
from power_testdata import PLAN, PROTOCOL, SEED

from studyctl.cli.app import main


def _run(args, capsys):
    code = main(["power", *map(str, args)])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_help_describes_every_option(capsys):
    code = main(["power", "--help"])
    out = capsys.readouterr().out
    assert code == 0
    for option in ("--plan", "--participants", "--replicates", "--seed", "--scheduler", "--workers",
                   "--memory-limit", "--out", "--population", "--effect", "--group-effect", "--between-sd"):
        assert option in out


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--plan", "bio_inspired_palpation"], "analyses protocol 'bio_inspired_palpation'"),
        (["--participants", "1,4"], "below the 2 counterbalancing sequences"),
        (["--effect", "linear-balloon_weber=1"], "--effect 'linear-balloon_weber=1': expected"),
        (["--effect", "linear:balloon_weber=big"], "'big' is not a number"),
        (["--between-sd", "aim_sd_mm=-1"], "must be ≥ 0"),
        (["--group-effect", "surgeons:aim_sd_mm=1"], "no group (stratum) 'surgeons'"),
        (["--population", "missing.yaml"], "population file 'missing.yaml' does not exist"),
        (["--memory-limit", "lots"], "--memory-limit 'lots'"),
        (["--scheduler", f"127.0.0.1:{_closed_port()}"], "cannot reach the Dask scheduler"),
        (["--target", "0"], "--target 0"),
        (["--target", "0.8", "--participants", "4,6"], "--participants 6"),
        (["--two-stage", "--pool", "10"], "the pool must hold at least 20 × the largest sample size"),
        (["--two-stage", "--pool-bootstrap", "1"], "--pool-bootstrap 1 with 50 replicates each"),
        (["--target", "1.5"], "strictly between 0 and 1"),
        (["--sim-rate-hz", "0"], "--sim-rate-hz (the simulation loop rate) must be a positive number of Hz"),
        # the mini study's loops are 50 Hz and not rate-adjustable: a cap would change nothing but the keys
        (["--sim-rate-hz", "250"], "--sim-rate-hz 250: slows no feedback loop of protocol"),
        (["--full-rate", "--sim-rate-hz", "500"], "--full-rate and --sim-rate-hz 500 contradict each other"),
        (["--two-stage", "--scheduler", f"127.0.0.1:{_closed_port()}"], "cannot reach the Dask scheduler"),
    ],
)
def test_bad_input_is_one_error_line_and_writes_nothing(extra, message, tmp_path, capsys):
    out = tmp_path / "report"
    sizes = [] if "--participants" in extra else ["--participants", "2,4"]
    args = [PROTOCOL, "--plan", PLAN, *sizes, "--replicates", "1", "--out", out, *extra]
    if "--two-stage" in extra:
        args += ["--pool-dir", tmp_path / "pools"]
    if "--plan" in extra:
        args = [PROTOCOL, "--participants", "4", "--out", out, *extra]
    code, stdout, stderr = _run(args, capsys)
    assert code != 0
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines and lines[0].startswith("Error: ") and message in stderr, stderr
    assert "Traceback" not in stderr
    assert not out.exists() and not (tmp_path / "pools").exists()


@pytest.mark.slow
def test_serial_run_states_the_population(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    pop = tmp_path / "population.yaml"
    pop.write_text("population:\n  group_effects:\n    expert: {aim_sd_mm: -1.0}\n", encoding="utf-8")
    code, stdout, stderr = _run([PROTOCOL, "--plan", PLAN, "--participants", "2", "--replicates", "1",
                                 "--seed", SEED, "--workers", "0", "--out", tmp_path / "out", "--population", pop,
                                 "--effect", "linear:balloon_weber=0.05", "--between-sd", "aim_sd_mm=0.2"], capsys)
    assert code == 0, stderr
    assert "serial, in this process" in stdout and "control_algorithm" in stdout
    # its loops are 50 Hz and not rate-adjustable: the default cap leaves them (no --full-rate needed)
    assert "loop rates: no_feedback, linear 50 Hz (the protocol's rates)" in stdout
    assert ("effects (shifts on top of each person's traits): linear: balloon_weber +0.05; expert: aim_sd_mm -1; "
            "SD(aim_sd_mm) = 0.2") in stdout
    stated = pd.read_csv(tmp_path / "out" / "power_population.csv").set_index("parameter")
    assert stated.loc["aim_sd_mm", "group:expert"] == -1.0 and stated.loc["aim_sd_mm", "between_sd"] == 0.2
    assert stated.loc["balloon_weber", "condition:linear"] == 0.05
    # the same command again only reuses what is there
    code, stdout, stderr = _run([PROTOCOL, "--plan", PLAN, "--participants", "2", "--replicates", "1",
                                 "--seed", SEED, "--workers", "0", "--out", tmp_path / "out", "--population", pop,
                                 "--effect", "linear:balloon_weber=0.05", "--between-sd", "aim_sd_mm=0.2"], capsys)
    assert code == 0 and "continuing: 1 of 1 replicates already in" in stderr
    assert "simulated 0 replicate(s), reused 1" in stdout


@pytest.mark.slow
@pytest.mark.parametrize(("extra", "rate"), [([], 250.0), (["--sim-rate-hz", "500"], 500.0), (["--full-rate"], None)])
def test_sim_rate_caps_the_replicates_loops_and_the_run_says_which_rates_it_used(extra, rate, tmp_path, capsys,
                                                                                 monkeypatch):
    """The cap (by default the demo's 250 Hz; --full-rate: none) reaches every simulated session, and the printed
    line, the JSON and power_run.json name the rates (seed 002: its haptic condition's 1 kHz loop is
    rate-adjustable, the manual one has no loop)."""
    import json

    import studyctl.power.replicate as replicate

    seen = []
    real = replicate.run_session

    def spy(*args, **kwargs):
        seen.append(kwargs.get("sim_rate_hz"))
        return real(*args, **kwargs)

    monkeypatch.setattr(replicate, "run_session", spy)
    out = tmp_path / "out"
    code, stdout, stderr = _run(["data_driven_palpation", "-n", "2", "-r", "1", "--workers", "0", *extra,
                                 "--out", out, "--json"], capsys)
    assert code == 0, stderr
    assert seen == [rate, rate]
    loop = 1000.0 if rate is None else rate
    how = "the protocol's rates" if rate is None else f"rate-adjustable loops capped at {rate:g} Hz"
    assert f"loop rates: haptic {loop:g} Hz ({how}" in stderr
    doc = json.loads(stdout)
    assert doc["sim_rate_hz"] == rate and doc["loop_rates_hz"] == {"haptic": loop}
    settings = json.loads((out / "power_run.json").read_text(encoding="utf-8"))
    assert settings["loop_rates_hz"] == {"haptic": loop} and settings["fingerprint"]["sim_rate_hz"] == rate


def test_the_power_figure_names_a_capped_loop_rate_in_the_words_the_run_printed():
    from studyctl.power import prepare_power
    from studyctl.report.loop_rates import loop_rates_line
    from studyctl.workflows.power import rates_note

    spec = prepare_power("data_driven_palpation", sizes="2", replicates=1, sim_rate_hz=250)
    assert rates_note(spec) == loop_rates_line(spec.loop_rates(), spec.sim_rate_hz)
    assert rates_note(spec) == ("loop rates: haptic 250 Hz (rate-adjustable loops capped at 250 Hz; --full-rate for "
                                "the protocol's rates)")
    assert rates_note(prepare_power("data_driven_palpation", sizes="2", replicates=1)) is None


def test_a_specs_loop_rates_parse_its_protocol_once(monkeypatch):
    """A run asks its spec for the loop rates 3-4 times (printed line, figure note, power_run.json, result): the
    protocol text is parsed and planned for them once; a copy with another cap answers for its own cap, and the
    answer survives the pickling that sends a spec to workers."""
    import dataclasses
    import pickle

    import studyctl.power.spec as spec_module
    from studyctl.power import prepare_power

    spec = prepare_power("data_driven_palpation", sizes="2", replicates=1, sim_rate_hz=250)
    parsed = []
    real = spec_module.load_protocol_text
    monkeypatch.setattr(spec_module, "load_protocol_text", lambda *a: parsed.append(a) or real(*a))
    spec.loop_rates()["haptic"] = 1.0  # a caller's change stays its own
    assert [spec.loop_rates() for _ in range(3)] == [{"haptic": 250.0}] * 3
    assert len(parsed) == 1
    assert dataclasses.replace(spec, sim_rate_hz=500.0).loop_rates() == {"haptic": 500.0}
    assert pickle.loads(pickle.dumps(spec)).loop_rates() == {"haptic": 250.0}
