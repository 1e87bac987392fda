"""``studyctl bench schedule``: how fast protocols expand into participants' stored plans.

The headline figure ``participants_per_s`` expands 10,000 participants of the seed-000 protocol
(Williams order within two strata, 3 tumours placed in 7 holes with every tumour moving each trial),
i.e. schedules *with placements*; the goal is 10,000 participants in under 1 s. The other shipped
protocols are measured alongside. There is no peer library: none of the tools we surveyed expands
stored, seeded per-participant plans with placements.
"""

from __future__ import annotations

import time

import numpy as np

from studyctl.bench import BenchResult, time_calls
from studyctl.protocol import Planner, allocate_strata, load_protocol, resolve_protocol

PROTOCOLS = ("bio_inspired_palpation", "needle_insertion", "data_driven_palpation", "pseudo_haptic_palpation")
HEADLINE = "bio_inspired_palpation"


def _expand_all(protocol, allocation, seed: int) -> int:
    planner = Planner(protocol)  # built inside the timed call: a cold start per run
    return sum(len(s.entries) for s in planner.expand_batch(seed=seed, pairs=allocation))


def run(quick: bool = False) -> BenchResult:
    """Time the expansion of N participants' plans (N = 10,000; 1,000 with ``quick``)."""
    n = 1_000 if quick else 10_000
    repeat = 1 if quick else 5
    figures: dict[str, float] = {}
    rows = []
    for name in PROTOCOLS:
        path = resolve_protocol(name)
        t0 = time.perf_counter()
        protocol = load_protocol(path)
        load_s = time.perf_counter() - t0
        allocation = allocate_strata(protocol, n)
        trials = _expand_all(protocol, allocation, 1)
        cpu0 = time.process_time()
        times = time_calls(lambda p=protocol, a=allocation: _expand_all(p, a, 1), repeat=repeat, warmup=1)
        cpu_per_run = (time.process_time() - cpu0) / (repeat + 1)
        best, median = float(times.min()), float(np.median(times))
        rows.append({
            "protocol": name,
            "participants": n,
            "trials": trials,
            "median_s": median,
            "best_s": best,
            "participants_per_s": n / median,
            "participants_per_cpu_s": n / cpu_per_run,
            "load_ms": load_s * 1e3,
        })
        figures[f"participants_per_s_{name}"] = n / median
        if name == HEADLINE:
            figures["participants_per_s"] = n / median
            figures["participants_per_cpu_s"] = n / cpu_per_run
            figures["seconds_per_10000"] = median * 10_000 / n
            figures["trials_per_s"] = trials / median
    return BenchResult(
        name="schedule",
        figures=dict(sorted(figures.items(), key=lambda kv: (kv[0] != "participants_per_s", kv[0]))),
        tables={"protocols": rows},
        notes=[
            f"{n} participants per protocol, allocated over strata by target_n, expanded with "
            f"Planner.expand_batch (identical plans to expand); median of {repeat} runs after 1 warm-up, each run "
            "building its Planner from scratch.",
            "participants_per_s is the seed-000 protocol (placements of 3 tumours in 7 holes, every tumour "
            "moving each trial); goal: >= 10,000 participants/s.",
            "participants_per_cpu_s divides by this process's CPU time instead of wall time: on a shared, "
            "loaded machine it shows the work done, not the wait for a core.",
            "No peer: no surveyed tool expands seeded per-participant plans with placements.",
        ],
    )
