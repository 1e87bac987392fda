"""``studyctl bench calibration``: how well the shipped (calibrated) populations reproduce their papers.

It runs ``studyctl demo`` (the four reference studies at the papers' sizes, each drawn from its shipped
population, through the real engine) and reads every study's ``agreement.csv`` (its "simulated vs published"
section). Figures per study and overall, separately for fit and validation targets: the fraction of directions
right, of significance verdicts reproduced, of means/medians/proportions inside the published band, of SDs within
a factor of 1.5 (and the median SD ratio), and of targets agreeing on every check, each with its count
(``…_n``: the targets the check applies to), for ``fit``, ``validation`` and ``all``; and issue 17's goals per
study and role (``….goal_direction_met`` etc., 1 or 0; the ``goals`` table gives value and bar). A study with no shipped
targets has no figures (a note says so). The calibration wall/CPU seconds are the ones the calibration that wrote
each shipped population measured and recorded in it (``calibration.seconds`` / ``cpu_seconds``), where present.
``--quick``: 2 participants per study (a smoke run: the fractions then mean little).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from studyctl.bench import BenchResult

FIGURES = (("direction", "direction_fraction"), ("verdict", "verdict_fraction"), ("within", "within_fraction"),
           ("sd_within", "sd_ratio_within_fraction"), ("sd_ratio_median", "sd_ratio_median"),
           ("agree", "agree_fraction"))
COUNTS = (("direction_n", "direction_n"), ("verdict_n", "verdict_n"), ("within_n", "within_n"),
          ("sd_n", "sd_ratio_n"), ("agree_n", "agree_n"), ("targets", "targets"))
ROLES = ("fit", "validation", "all")
# issue 17's bars: (goal, summary key, bar, how the fraction is compared); every direction right, ≥ 80 % of the
# verdicts reproduced, ≥ 80 % of the values inside their published band, every SD within a factor of 1.5
GOALS = (("direction", "direction_fraction", 1.0), ("verdict", "verdict_fraction", 0.8),
         ("within", "within_fraction", 0.8), ("sd_within", "sd_ratio_within_fraction", 1.0))


def _summarise(scope: str, summary: dict, figures: dict[str, float], rows: list, goals: list) -> None:
    """Figures ``{scope}.{role}.{rate}`` with their counts ``…_n``, a row per role and each goal met or not."""
    for role in ROLES:
        s = summary[role]
        if not s["targets"]:
            continue
        for name, key in FIGURES + COUNTS:
            v = s[key]
            if v is not None:
                figures[f"{scope}.{role}.{name}"] = float(v)
        rows.append({"study": scope, "role": role, "targets": s["targets"],
                     **{name: s[key] for name, key in FIGURES},
                     **{name: s[key] for name, key in COUNTS if name != "targets"}})
        for goal, key, bar in GOALS:
            v = s[key]
            if v is None:
                continue
            met = v >= bar - 1e-12
            figures[f"{scope}.{role}.goal_{goal}_met"] = float(met)
            goals.append({"study": scope, "role": role, "goal": goal, "value": v, "bar": bar, "met": met})


def run(quick: bool = False) -> BenchResult:
    import pandas as pd

    from studyctl.calibration.agreement import summary_from_frame
    from studyctl.populations import load_population_file, shipped_population_path
    from studyctl.workflows.demo import REFERENCE_STUDIES, run_demo

    studies = [(name, 2) for name, _ in REFERENCE_STUDIES] if quick else list(REFERENCE_STUDIES)
    figures: dict[str, float] = {}
    rows, notes, frames, goals = [], [], [], []
    c0 = time.process_time()
    with tempfile.TemporaryDirectory(prefix="studyctl-bench-calibration-") as tmp:
        t0 = time.perf_counter()
        result = run_demo(os.path.join(tmp, "reports"), studies=studies)
        figures["demo_s"] = time.perf_counter() - t0
        for s in result.studies:
            path = Path(s.report).parent / "agreement.csv" if s.report else None
            pop_path = shipped_population_path(s.study)
            if pop_path is not None:
                cal = load_population_file(pop_path).calibration
                for key in ("seconds", "cpu_seconds"):
                    if cal.get(key) is not None:
                        figures[f"{s.study}.calibration_{key.replace('seconds', 's')}"] = float(cal[key])
            if s.error or path is None or not path.is_file():
                why = f"FAILED: {s.error.splitlines()[0]}" if s.error else "no shipped targets"
                notes.append(f"{s.study}: no agreement table ({why}; {s.population or 'population unknown'})")
                continue
            frame = pd.read_csv(path, keep_default_na=True)
            for col in ("same_direction", "within", "same_verdict", "agrees"):
                frame[col] = frame[col].map(lambda v: None if pd.isna(v) else str(v) == "True")
            frames.append(frame.assign(study=s.study))
            _summarise(s.study, summary_from_frame(frame), figures, rows, goals)
            notes.append(f"{s.study}: {s.population}")
    if frames:
        _summarise("overall", summary_from_frame(pd.concat(frames, ignore_index=True)), figures, rows, goals)
    figures["bench_cpu_s_main_process"] = time.process_time() - c0
    notes.insert(0, f"{'quick: 2 participants per study' if quick else 'paper-sized cohorts'} from each protocol's "
                 f"shipped population, {result.workers} worker processes on {os.cpu_count()} cores; fractions over "
                 "the targets where the check applies; goals (issue 17): directions all right, ≥ 80 % verdicts and "
                 "≥ 80 % within band, SD ratios within 1.5×, for fit and validation targets alike")
    return BenchResult(name="calibration", figures=figures, tables={"agreement": rows, "goals": goals}, notes=notes)
