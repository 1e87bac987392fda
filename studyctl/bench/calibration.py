"""``studyctl bench calibration``: how well the shipped (calibrated) populations reproduce their papers.

It runs ``studyctl demo`` (the four reference studies at the papers' sizes, each drawn from its shipped
population, through the real engine) and reads every study's ``agreement.csv`` (its "simulated vs published"
section). Figures per study and overall, separately for fit and validation targets: the fraction of directions
right, of significance verdicts reproduced, of means/medians/proportions inside the published band, of SDs within
a factor of 1.5 (and the median SD ratio), and of targets agreeing on every check. A study with no shipped
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


def run(quick: bool = False) -> BenchResult:
    import pandas as pd

    from studyctl.calibration.agreement import summary_from_frame
    from studyctl.populations import load_population_file, shipped_population_path
    from studyctl.workflows.demo import REFERENCE_STUDIES, run_demo

    studies = [(name, 2) for name, _ in REFERENCE_STUDIES] if quick else list(REFERENCE_STUDIES)
    figures: dict[str, float] = {}
    rows, notes, frames = [], [], []
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
            summary = summary_from_frame(frame)
            for role in ("fit", "validation"):
                for name, key in FIGURES:
                    v = summary[role][key]
                    if v is not None:
                        figures[f"{s.study}.{role}.{name}"] = float(v)
                rows.append({"study": s.study, "role": role, "targets": summary[role]["targets"],
                             **{name: summary[role][key] for name, key in FIGURES}})
            notes.append(f"{s.study}: {s.population}")
    if frames:
        overall = summary_from_frame(pd.concat(frames, ignore_index=True))
        for role in ("fit", "validation"):
            for name, key in FIGURES:
                v = overall[role][key]
                if v is not None:
                    figures[f"overall.{role}.{name}"] = float(v)
            rows.append({"study": "overall", "role": role, "targets": overall[role]["targets"],
                         **{name: overall[role][key] for name, key in FIGURES}})
    figures["bench_cpu_s_main_process"] = time.process_time() - c0
    notes.insert(0, f"{'quick: 2 participants per study' if quick else 'paper-sized cohorts'} from each protocol's "
                 f"shipped population, {result.workers} worker processes on {os.cpu_count()} cores; fractions over "
                 "the targets where the check applies; goals (issue 17): directions all right, ≥ 80 % verdicts and "
                 "≥ 80 % within band, SD ratios within 1.5×, for fit and validation targets alike")
    return BenchResult(name="calibration", figures=figures, tables={"agreement": rows}, notes=notes)
