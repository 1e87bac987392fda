"""``studyctl bench calibration`` turns each demo study's agreement table into figures per study and role."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd


@dataclass
class _Study:
    study: str
    report: str
    error: str = ""
    population: str = "population: test"


def test_figures_from_agreement_tables(tmp_path, monkeypatch):
    import studyctl.workflows.demo as demo
    from studyctl.bench.calibration import run

    folder = tmp_path / "bio_inspired_palpation"
    folder.mkdir()
    pd.DataFrame([
        {"target": "a", "role": "fit", "statistic": "mean", "same_direction": True, "within": True,
         "sd_ratio": float("nan"), "same_verdict": None, "agrees": True},
        {"target": "b", "role": "fit", "statistic": "sd", "same_direction": None, "within": False,
         "sd_ratio": 2.0, "same_verdict": None, "agrees": False},
        {"target": "c", "role": "validation", "statistic": "verdict", "same_direction": None, "within": None,
         "sd_ratio": float("nan"), "same_verdict": False, "agrees": False},
        {"target": "d", "role": "validation", "statistic": "pct_change_vs_baseline", "same_direction": True,
         "within": False, "sd_ratio": float("nan"), "same_verdict": None, "agrees": False},
    ]).to_csv(folder / "agreement.csv", index=False)

    class _Result:
        workers = 1
        studies = [_Study("bio_inspired_palpation", str(folder / "report.html")),
                   _Study("needle_insertion", "", error="boom")]

    monkeypatch.delenv("STUDYCTL_BENCH_SEEDS", raising=False)
    monkeypatch.setattr(demo, "run_demo", lambda out, seed, studies: _Result())
    res = run(quick=True)
    f = res.figures
    assert f["bio_inspired_palpation.fit.within"] == 1.0  # the SD is judged by its ratio, not the band
    assert f["bio_inspired_palpation.fit.sd_within"] == 0.0 and f["bio_inspired_palpation.fit.sd_ratio_median"] == 2.0
    assert f["bio_inspired_palpation.validation.verdict"] == 0.0
    assert f["bio_inspired_palpation.validation.direction"] == 1.0
    assert f["bio_inspired_palpation.validation.within"] == 0.0
    assert f["overall.fit.agree"] == 0.5 and "needle_insertion.fit.agree" not in f
    # counts beside the rates, all targets together, and the goals per study and role
    assert f["bio_inspired_palpation.fit.within_n"] == 1 and f["bio_inspired_palpation.fit.sd_n"] == 1
    assert f["bio_inspired_palpation.all.targets"] == 4 and f["overall.all.direction"] == 1.0
    assert f["overall.all.direction_n"] == 2 and f["overall.all.verdict_n"] == 1
    assert f["overall.validation.goal_direction_met"] == 1.0 and f["overall.validation.goal_verdict_met"] == 0.0
    assert f["overall.fit.goal_within_met"] == 1.0 and f["overall.fit.goal_sd_within_met"] == 0.0
    goals = {(g["study"], g["role"], g["goal"]): g for g in res.tables["goals"]}
    assert goals[("overall", "all", "within")]["value"] == 0.5 and goals[("overall", "all", "within")]["bar"] == 0.8
    assert not goals[("overall", "all", "within")]["met"]
    assert any("needle_insertion: no agreement table (FAILED: boom" in n for n in res.notes)
    assert Path(folder / "agreement.csv").is_file()


def test_several_seeds_pool_their_targets_and_keep_each_seeds_figures(tmp_path, monkeypatch):
    import studyctl.workflows.demo as demo
    from studyctl.bench.calibration import run

    def _result(seed: int):
        folder = tmp_path / str(seed) / "data_driven_palpation"
        folder.mkdir(parents=True)
        verdict = seed != 2024  # the demo seed misses the verdict, the other seed reproduces it
        pd.DataFrame([
            {"target": "v", "role": "validation", "statistic": "verdict", "same_direction": None, "within": None,
             "sd_ratio": float("nan"), "same_verdict": verdict, "agrees": verdict},
        ]).to_csv(folder / "agreement.csv", index=False)

        class _Result:
            workers = 1
            studies = [_Study("data_driven_palpation", str(folder / "report.html"))]
        return _Result()

    monkeypatch.setenv("STUDYCTL_BENCH_SEEDS", "2024,99")
    monkeypatch.setattr(demo, "run_demo", lambda out, seed, studies: _result(seed))
    f = run(quick=True).figures
    assert f["seed2024.data_driven_palpation.all.verdict"] == 0.0
    assert f["seed99.data_driven_palpation.all.verdict"] == 1.0
    assert f["data_driven_palpation.validation.verdict"] == 0.5 and f["data_driven_palpation.validation.verdict_n"] == 2
    assert f["overall.all.verdict_n"] == 2 and "demo_s_seed99" in f


def test_seeds_that_are_not_distinct_integers_are_refused(monkeypatch):
    import pytest

    from studyctl.bench.calibration import bench_seeds
    from studyctl.errors import ConfigError

    monkeypatch.setenv("STUDYCTL_BENCH_SEEDS", "2024,x")
    with pytest.raises(ConfigError, match="STUDYCTL_BENCH_SEEDS='2024,x'.*e.g. STUDYCTL_BENCH_SEEDS=2024,99,7"):
        bench_seeds(2024)
    monkeypatch.setenv("STUDYCTL_BENCH_SEEDS", "7,7")
    with pytest.raises(ConfigError):
        bench_seeds(2024)
    monkeypatch.delenv("STUDYCTL_BENCH_SEEDS")
    assert bench_seeds(2024) == [2024]
