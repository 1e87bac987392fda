"""``studyctl bench simrate``: speed against error of running simulated 1 kHz loops at a lower rate.

The same seeded virtual cohort (same schedules, placements and random streams) runs through the engine once
per loop rate: the protocol's 1 kHz, then the reduced rates a simulation may use (``run_session(sim_rate_hz=…)``;
the simulated device keeps integrating its physics at 1 kHz under the held force). Each cohort is analysed
with the study's shipped plan, and its metric values are compared, trial by trial, with the 1 kHz run's:

* ``cpu_s_per_participant``: CPU seconds of one participant's whole session (this process, sequential);
* ``time_rel_err``: mean |Δ| / 1 kHz value of the duration metric (completion / detection time);
* ``time_rel_bias``: the same difference with its sign (a systematic shift shows here);
* ``found_agree``: share of per-nodule found/missed outcomes identical to the 1 kHz run, and the discordant
  ones: ``found_gained`` (found only at the reduced rate) and ``found_lost`` (found only at 1 kHz);
* ``se_diff_pp``: pooled sensitivity (nodules found over nodules, all conditions) difference in percentage
  points, beside the 1 kHz run's Wilson 95 % half-width (``se_ci_half_pp``): the sampling uncertainty the
  study itself reports.

A participant's later presses follow from earlier ones, so a small numerical difference can change what
follows (another press, another random draw): the differences are an upper bound on the loop rate's effect,
and they are judged against the study's own uncertainty.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import pandas as pd

from studyctl.bench import BenchResult

RATES_HZ = (1000.0, 500.0, 250.0, 125.0)
QUICK_RATES_HZ = (1000.0, 250.0)
STUDIES = {  # protocol: (participants, quick participants, duration metric)
    "pseudo_haptic_palpation": (8, 0, "detection_time"),
    "data_driven_palpation": (6, 1, "completion_time"),
}
SEED = 2024


def _cohort_metrics(protocol: str, n: int, rate: float | None, folder: Path) -> tuple[pd.DataFrame, float, float]:
    """Metric values of an ``n``-participant cohort at loop-rate cap ``rate``, CPU and wall s per participant."""
    from studyctl.analysis.plan import load_plan
    from studyctl.analysis.run import analyze
    from studyctl.store.workspace import open_study
    from studyctl.workflows.simulate import create_cohort, relax_sqlite_durability, run_participant

    cohort = create_cohort(protocol, n, SEED, folder, sim_rate_hz=rate)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    with open_study(cohort.db, cohort.workspace, cohort.study) as opened:
        relax_sqlite_durability(opened.store)
        for code in cohort.codes:
            run_participant(cohort, code, store=opened.store)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    frame = analyze(load_plan(protocol), workspace=cohort.workspace).data.to_frame()
    return frame, cpu / n, wall / n


def _compare(ref: pd.DataFrame, other: pd.DataFrame, duration: str) -> dict[str, float]:
    key = ["participant", "condition", "metric", "level"]
    merged = ref.merge(other, on=key, suffixes=("_ref", "_x"), how="outer")
    dur = merged[merged["metric"] == duration]
    dur = dur[dur["value_ref"] > 0]
    signed = (dur["value_x"] - dur["value_ref"]) / dur["value_ref"]
    rel = signed.abs()
    found = merged[(merged["metric"] == "sensitivity") & merged["level"].notna()]
    agree = float((found["value_ref"] == found["value_x"]).mean()) if len(found) else math.nan
    se_ref = found["value_ref"].sum() / found["denominator_ref"].sum()
    se_x = found["value_x"].sum() / found["denominator_x"].sum()
    return {
        "time_rel_err": float(rel.mean()),
        "time_rel_bias": float(signed.mean()),
        "time_rel_err_max": float(rel.max()),
        "found_agree": agree,
        # discordant nodules: found only at this rate / only at 1 kHz (a bias shows as an imbalance)
        "found_gained": int((found["value_x"] > found["value_ref"]).sum()),
        "found_lost": int((found["value_x"] < found["value_ref"]).sum()),
        "se_ref": float(se_ref),
        "se_diff_pp": float(100.0 * (se_x - se_ref)),
    }


def _wilson_half_pp(k: float, n: float) -> float:
    from studyctl.stats import wilson_interval

    ci = wilson_interval(int(round(k)), int(round(n)))
    return float(100.0 * (ci.upper - ci.lower) / 2.0)


def run(quick: bool = False) -> BenchResult:
    figures: dict[str, float] = {}
    rows = []
    with tempfile.TemporaryDirectory(prefix="studyctl-bench-simrate-") as tmp:
        for protocol, (n_full, n_quick, duration) in STUDIES.items():
            n = n_quick if quick else n_full
            if n == 0:
                continue
            ref = None
            ref_cpu = math.nan
            for rate in QUICK_RATES_HZ if quick else RATES_HZ:
                frame, cpu, wall = _cohort_metrics(protocol, n, None if rate == 1000.0 else rate,
                                                   Path(tmp) / f"{protocol}-{int(rate)}")
                row: dict[str, float | str] = {"study": protocol, "rate_hz": rate, "participants": n,
                                               "cpu_s_per_participant": cpu, "wall_s_per_participant": wall}
                if ref is None:
                    ref, ref_cpu = frame, cpu
                    pooled = frame[(frame["metric"] == "sensitivity") & frame["level"].notna()]
                    half = _wilson_half_pp(pooled["value"].sum(), pooled["denominator"].sum())
                    row.update(speedup=1.0, time_rel_err=0.0, time_rel_bias=0.0, found_agree=1.0, found_gained=0,
                               found_lost=0, se_diff_pp=0.0, se_ci_half_pp=half)
                else:
                    row.update(speedup=ref_cpu / cpu, **_compare(ref, frame, duration))
                    row.pop("time_rel_err_max", None)
                    row.pop("se_ref", None)
                    tag = f"{int(rate)}_{protocol}"
                    figures[f"speedup_{tag}"] = ref_cpu / cpu
                    figures[f"time_rel_err_{tag}"] = float(row["time_rel_err"])
                    figures[f"found_agree_{tag}"] = float(row["found_agree"])
                    figures[f"se_diff_pp_{tag}"] = float(row["se_diff_pp"])
                figures[f"cpu_s_per_participant_{int(rate)}_{protocol}"] = cpu
                rows.append(row)
    notes = [
        f"seed {SEED}; the same cohort per rate "
        f"({'quick: one seed-002 participant, two rates' if quick else 'see participants'}); "
        "CPU seconds in this process, sessions run one after another",
        "time_rel_err: mean |duration - duration at 1 kHz| / duration at 1 kHz over trials; found_agree: per-nodule "
        "found/missed outcomes equal to the 1 kHz run's; se_diff_pp: pooled sensitivity minus the 1 kHz run's, "
        "percentage points, against the 1 kHz run's Wilson 95 % half-width se_ci_half_pp",
        "participants' later actions depend on earlier ones, so differences include divergence after a first "
        "small numerical difference: they bound the loop rate's effect from above",
    ]
    figures["rates_tested"] = float(len({r["rate_hz"] for r in rows}))
    return BenchResult(name="simrate", figures=figures, tables={"rates": rows}, notes=notes)
