"""``studyctl calibrate`` on the small palpation study: it fits, resumes from its journal, flags a parameter the
targets cannot identify, writes every file whole, and reports a report's simulated-vs-published section."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest
from population_testdata import DATA, MINI_PLAN, MINI_PROTOCOL, POPULATION, write_variant

from studyctl.errors import PopulationError, UsageError

TARGETS = DATA / "mini.targets.yaml"


@pytest.fixture
def protocol(tmp_path):
    # the study's protocol name is the file stem: name the copy as the plan's protocol
    path = tmp_path / "power_mini_palpation.yaml"
    shutil.copy(MINI_PROTOCOL, path)
    return path


@pytest.fixture
def population_with_inert_trait(tmp_path):
    """The test population plus vibration_weber, which the two conditions (no vibration) cannot show."""
    return write_variant(tmp_path, "fixed: {hold_s: 0.3}", "  vibration_weber:\n    dist: normal\n    mean: 0.25\n"
                         "    sd: 0.05\n    range: [0.05, 0.6]\n    source: \"CHOSEN: test\"\nfixed: {hold_s: 0.3}")


@pytest.mark.slow
def test_calibrate_fits_resumes_and_flags_unidentified(tmp_path, protocol, population_with_inert_trait):
    from studyctl.workflows.calibrate import prepare_calibration, run_calibration

    out = tmp_path / "out" / "fitted.yaml"
    spec = prepare_calibration(protocol, TARGETS, population=population_with_inert_trait,
                               free="press_speed_mm_s,vibration_weber", participants=4, evaluations=6, out=out)
    seen = []
    result = run_calibration(spec, on_progress=lambda i, n, m: seen.append((i, n)))
    assert seen[-1][0] == seen[-1][1] == 6 + 2 * 2 + 1
    assert result.best_distance <= result.start_distance
    est = {e.name: e for e in result.estimates}
    assert not est["vibration_weber"].identified and est["vibration_weber"].profile_rise < 1.0
    assert est["vibration_weber"].se == float("inf")
    for kind in ("population", "report_md", "report_html", "report_csv", "agreement", "journal"):
        assert result.files[kind].is_file(), kind
    assert not list(out.parent.glob(".*.tmp"))
    from studyctl.populations import load_population_file

    fitted = load_population_file(out)  # the written file is a valid population
    assert fitted.version == 2 and fitted.calibration["used_for_fit"] == ["time_nofb_mean", "time_nofb_sd"]
    assert fitted.calibration["validation"] == ["time_linear_mean", "accuracy_linear", "kw_time_verdict"]
    assert fitted.trait("press_speed_mm_s").source.startswith("FITTED")
    assert fitted.trait("press_speed_mm_s").mean == pytest.approx(est["press_speed_mm_s"].estimate, rel=1e-5)
    assert fitted.trait("balloon_weber").source.startswith("CITED")
    report = result.files["report_md"].read_text()
    assert "Not identified by these targets" in report and "vibration_weber" in report
    assert "Simulated vs published" in report
    agr = pd.read_csv(result.files["agreement"])
    assert list(agr["target"]) == ["time_nofb_mean", "time_nofb_sd", "time_linear_mean", "accuracy_linear",
                                   "kw_time_verdict"]
    # a rerun continues from the journal: nothing is simulated again, the same answer
    again = run_calibration(spec)
    assert again.reused == 6 + 2 * 2 and again.best_distance == result.best_distance
    assert [e.estimate for e in again.estimates] == [e.estimate for e in result.estimates]
    assert again.seconds < result.seconds


@pytest.mark.slow
def test_unreachable_targets_finish_and_say_what_was_missed(tmp_path, protocol):
    from studyctl.workflows.calibrate import prepare_calibration, run_calibration

    far = write_variant(tmp_path, "value: 20.0", "value: 900.0", source=TARGETS)
    far.write_text(far.read_text().replace("plan: ../../power/data/", f"plan: {MINI_PLAN.parent}/"))
    spec = prepare_calibration(protocol, far, population=POPULATION, free="report_z", participants=4,
                               evaluations=3, out=tmp_path / "far.yaml")
    result = run_calibration(spec)
    assert any(m.startswith("time_nofb_mean: published 900") and "σ" in m for m in result.missed)
    assert "did not reach" in result.files["report_md"].read_text()
    assert result.files["population"].is_file()


def test_bad_calibration_input(tmp_path, protocol):
    from studyctl.workflows.calibrate import prepare_calibration

    with pytest.raises(PopulationError, match="did you mean 'report_z'"):
        prepare_calibration(protocol, TARGETS, population=POPULATION, free="report_zz", out=tmp_path / "a.yaml")
    with pytest.raises(PopulationError, match="no stratum 'experts'; did you mean 'expert'"):
        prepare_calibration(protocol, TARGETS, population=POPULATION, free="press_speed_mm_s@experts")
    with pytest.raises(PopulationError, match="has no shipped population"):
        prepare_calibration(protocol, TARGETS, free="report_z", out=tmp_path / "a.yaml")
    with pytest.raises(UsageError, match="--participants"):
        prepare_calibration(protocol, TARGETS, population=POPULATION, free="report_z", participants=1)
    no_fit = write_variant(tmp_path, "role: fit", "role: validation", source=TARGETS)
    no_fit.write_text(no_fit.read_text().replace("role: fit", "role: validation")
                      .replace("plan: ../../power/data/", f"plan: {MINI_PLAN.parent}/"))
    with pytest.raises(PopulationError, match="no role: fit target"):
        prepare_calibration(protocol, no_fit, population=POPULATION, free="report_z")
    assert not list(tmp_path.glob("a.yaml*"))


def test_cli_calibrate_bad_free_parameter_is_one_error_line(tmp_path, protocol, capsys):
    from studyctl.cli.app import main

    code = main(["calibrate", str(protocol), "--targets", str(TARGETS), "--population", str(POPULATION),
                 "--free", "press_sped_mm_s", "--out", str(tmp_path / "x.yaml")])
    err = capsys.readouterr().err
    assert code != 0 and "Traceback" not in err
    (line,) = [x for x in err.splitlines() if x.startswith("Error:")]
    assert "did you mean 'press_speed_mm_s'" in line


@pytest.mark.slow
def test_simulated_report_compares_with_published(tmp_path, protocol):
    from studyctl.analysis.plan import load_plan
    from studyctl.workflows.report import build_report
    from studyctl.workflows.simulate import simulate_study

    simulate_study(protocol, 4, 3, tmp_path / "ws", population=POPULATION)
    rep = build_report(load_plan(MINI_PLAN), tmp_path / "rep", workspace=tmp_path / "ws", targets=TARGETS)
    agreement = tmp_path / "rep" / "agreement.csv"
    assert agreement in rep.files.tables
    frame = pd.read_csv(agreement)
    assert {"published", "published_low", "published_high", "simulated", "simulated_low", "simulated_high",
            "same_direction", "within", "same_verdict", "role"} <= set(frame.columns)
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## Simulated vs published" in md and "palpator_small v1" in md
    # the summary of findings names the agreement first; the section itself follows the analyses
    summary = md[md.index("## Summary of findings"):md.index("## Statistical methods")]
    assert "Simulated vs published" in summary
    # without targets for its protocol the section says so
    rep2 = build_report(load_plan(MINI_PLAN), tmp_path / "rep2", workspace=tmp_path / "ws")
    md2 = (tmp_path / "rep2" / "report.md").read_text()
    assert "none shipped for power_mini_palpation" in md2 and not (tmp_path / "rep2" / "agreement.csv").exists()
    assert rep2.files.html.is_file()


@pytest.mark.slow
def test_replicates_run_on_a_dask_scheduler(tmp_path, protocol):
    distributed = pytest.importorskip("distributed")
    from studyctl.workflows.calibrate import evaluate, prepare_calibration

    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as lc:
        spec = prepare_calibration(protocol, TARGETS, population=POPULATION, free="report_z", participants=2,
                                   replicates=2, evaluations=2, out=tmp_path / "d.yaml", scheduler=lc.scheduler_address)
        with distributed.Client(lc.scheduler_address) as client:
            remote = evaluate(spec, {"report_z": 3.0}, client=client)
    local = evaluate(spec, {"report_z": 3.0})
    # the same seeds on the cluster and locally: the same simulated statistics
    pd.testing.assert_frame_equal(remote.stats, local.stats)
    assert remote.distance == local.distance


def test_a_failed_simulation_costs_a_large_distance_and_is_not_cached(tmp_path, protocol, monkeypatch):
    import studyctl.workflows.calibrate as cal
    import studyctl.workflows.calibration_runs as runs
    from studyctl.errors import SessionError

    spec = cal.prepare_calibration(protocol, TARGETS, population=POPULATION, free="report_z", participants=2,
                                   evaluations=2, out=tmp_path / "f.yaml")

    def broken(*args, **kwargs):
        raise SessionError("device fault in the test")

    monkeypatch.setattr(runs, "_evaluate", broken)  # what evaluate() runs
    ev = cal.evaluate(spec, {"report_z": 3.0})
    assert ev.distance == cal.FAILED_DISTANCE
    assert all("simulation failed: device fault in the test" in n for n in ev.stats["note"])
    final = cal._final_run(spec, {"report_z": 3.0}, None)
    assert final.distance == cal.FAILED_DISTANCE
    assert not (tmp_path / "f.yaml.final.json").exists()  # the next run tries again


@pytest.mark.slow
def test_pilot_db_recovers_a_shifted_trait_within_its_standard_error(tmp_path, protocol):
    """A pilot simulated from a population whose press speed is 4 mm/s (not the starting 8): calibrating that
    trait to the pilot's own numbers (targets computed from its database, SEs from its participants) moves it to
    the pilot's value within the reported SE; the targets carry the pilot's sampling uncertainty."""
    from studyctl.populations import load_population_file
    from studyctl.workflows.calibrate import prepare_calibration, run_calibration
    from studyctl.workflows.simulate import simulate_study

    for sub in ("pilot_pop", "start_pop"):
        (tmp_path / sub).mkdir()
    # a slow press is where completion time depends most on the speed (above ~10 mm/s moving dominates)
    # (novices and experts alike: the test population's expert-only speed is dropped)
    def variant(folder: str, speed: float) -> Path:
        path = write_variant(tmp_path / folder, "mean: 6.0", f"mean: {speed}")
        path.write_text(path.read_text().replace("    groups: {expert: {mean: 9.0}}\n", ""))
        return path

    pilot_pop, start_pop = variant("pilot_pop", 4.0), variant("start_pop", 8.0)
    simulate_study(protocol, 12, 11, tmp_path / "pilot", population=pilot_pop)
    db = tmp_path / "pilot" / "study.db"
    # the test targets file as the template (it names the plan): its targets, values from the pilot; the
    # no-feedback mean is the one fit target (the SD of 12 people is kept for validation)
    template = write_variant(tmp_path, "statistic: sd\n    value: 3.0\n    uncertainty: {n: 8}\n    role: fit",
                             "statistic: sd\n    value: 3.0\n    uncertainty: {n: 8}\n    role: validation",
                             source=TARGETS)
    template.write_text(template.read_text().replace("plan: ../../power/data/", f"plan: {MINI_PLAN.parent}/"))
    spec = prepare_calibration(protocol, template, population=start_pop, free="press_speed_mm_s", pilot_db=str(db),
                               participants=4, replicates=2, evaluations=10, out=tmp_path / "fit" / "p.yaml")
    fit = {t.id: t for t in spec.targets.by_role("fit")}
    assert set(fit) == {"time_nofb_mean"}
    t = fit["time_nofb_mean"]
    assert t.value != 20.0  # the pilot's number, not the template's
    assert t.uncertainty["basis"] == "pilot" and t.uncertainty["n"] == 12 and t.published_se() > 0
    assert t.band() == "±1.96 pilot bootstrap SE"
    # the same pilot gives the same targets (the journal's fingerprint must not change between runs)
    again = prepare_calibration(protocol, template, population=start_pop, free="press_speed_mm_s", pilot_db=str(db),
                                participants=4, replicates=2, evaluations=10, out=tmp_path / "fit" / "p.yaml")
    assert again.targets.sha256 == spec.targets.sha256 and again.fingerprint() == spec.fingerprint()
    result = run_calibration(spec)
    (est,) = result.estimates
    assert est.start == pytest.approx(8.0)
    assert est.identified and 0 < est.se < 2.0, est
    assert abs(est.estimate - 4.0) <= 2 * est.se, est  # recovered: the pilot's 4 within 2 reported SEs
    assert abs(est.estimate - 8.0) > 2 * est.se, est  # and the starting 8 is rejected
    fitted = load_population_file(result.files["population"])
    assert fitted.trait("press_speed_mm_s").mean == pytest.approx(est.estimate, rel=1e-5)
    assert fitted.calibration["targets"] == "study.db"


@pytest.mark.slow
def test_cli_calibrate_json_is_one_document_with_estimates_and_agreement(tmp_path, protocol, capsys):
    import json

    from studyctl.cli.app import main

    code = main(["calibrate", str(protocol), "--targets", str(TARGETS), "--population", str(POPULATION),
                 "--free", "report_z", "--participants", "2", "--evaluations", "2", "--out",
                 str(tmp_path / "j.yaml"), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(out)  # stdout holds the document only; the readable lines went to stderr
    assert doc["format"] == "studyctl-calibration/1" and doc["free"] == ["report_z"]
    assert doc["used_for_fit"] == ["time_nofb_mean", "time_nofb_sd"]
    (est,) = doc["estimates"]
    assert est["name"] == "report_z" and est["start"] == pytest.approx(3.5)
    assert [r["target"] for r in doc["agreement"]][:2] == ["time_nofb_mean", "time_nofb_sd"]
    assert set(doc["summary"]) == {"fit", "validation", "all"}
    assert doc["files"]["population"] == str(tmp_path / "j.yaml") and len(doc["population"]["sha256"]) == 64
    assert "distance over the fit targets" in err
