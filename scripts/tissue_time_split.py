"""Where a seed-003 tissue palpator's search time goes, per condition, in the trial loop.

Usage: ``python scripts/tissue_time_split.py CONDITIONS SEEDS [name=value ...]``, e.g.
``manual,PHF,FF,PHF_FF 24`` (~4-5 min CPU for 96 trials).

The person is the shipped population's typical one (every trait at its location, the fixed values) with the
overrides. Per condition and seed (100, 101, ...) a fresh person does the condition's test trial (the block turned a
quarter turn) through the seed-003 block scene and, for the instrumented conditions, the simulated Omni-class device
and the condition's controller (the bare finger, ``direct_touch``, for manual) at 250 Hz; the scene, device and
person streams are the same seed in every condition. The person is only watched: each tick's time is booked to the
stage (survey, follow-up re-palpation) and phase (travel in the air with its settle, press descent, dwell at the
bottom, lift) it was in. Printed per condition, means per trial: the time split and the presses of each stage, the
dwell's planned hold and how much longer the press was held waiting for the push to be steady, the survey's early
stop, the spots re-palpated and their verdicts, reports, false reports, nodules found (a report within the
protocol's 10 mm) and the trial's duration. Why: stop 31 left the instrumented conditions 1.8-2.8x the paper's time
and PHF+FF the slowest, where the paper's people were fastest with it; this says which part of the search it is.
"""

from __future__ import annotations

import sys
import time
from collections import defaultdict

import numpy as np
from tissue_slide_fusion import CONTROLLERS, typical_person

from studyctl.devices.direct_touch import DirectTouchDevice
from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.models.palpation_metrics import score_trial
from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes.tissue import StiffnessTissueScene

PHASES = ("travel", "press", "dwell", "lift")


class Watched(VirtualTissuePalpator):
    """The same person, its ticks booked to (stage, phase) and each press's hold noted; it decides as before."""

    def begin_trial(self, info, rng):
        super().begin_trial(info, rng)
        self.split: dict[tuple[str, str], float] = defaultdict(float)
        self.holds: list[tuple[str, float, float]] = []  # stage, planned hold, time held

    def act(self, t, percept):
        # the tick's time belongs to the phase the person was in since its last tick
        self.split[(getattr(self, "_stage", "setup"), self._phase)] += max(t - self._t_prev, 0.0)
        return super().act(t, percept)

    def _record(self, press):
        self.holds.append((self._stage, press.get("hold", 0.0), self._phase_t))
        super()._record(press)


def trial(params: dict, cond: str, seed: int):
    scene = StiffnessTissueScene.build({"phantom": "seed003_block"}, {"orientation_deg": 90.0},
                                       (CONTROLLERS[cond].needs({}) | {"view"}) if cond != "manual" else set(),
                                       np.random.default_rng(seed))
    if cond == "manual":
        device, controller, visual, view = DirectTouchDevice({}, scene), None, "none", None
    else:
        device = SimulatedForceDevice({}, scene, np.random.default_rng(seed + 1))
        controller, visual, view = CONTROLLERS[cond]({}, scene), "realtime", scene.view
    device.open()
    info = TrialInfo(condition=cond, time_limit_s=900.0, rate_hz=250.0, visual=visual,
                     public={**scene.public(), "trial_index": 1})
    person = Watched(params)
    out = run_trial(info=info, controller=controller, device=device, participant=person, clock=SimulatedClock(),
                    rng=np.random.default_rng(seed + 2), view=view)
    device.close()
    score = score_trial(out.reports, scene.truth()["nodules"], hit_radius_mm=10.0, duration_s=out.duration_s)
    return person, out, score


def main(argv: list[str]) -> None:
    conds, seeds = argv[0].split(","), int(argv[1])
    params = typical_person(argv[2:])
    for cond in conds:
        t0 = time.process_time()
        split: dict[tuple[str, str], float] = defaultdict(float)
        n = defaultdict(float)
        verdicts: dict[str, int] = defaultdict(int)
        for seed in range(100, 100 + seeds):
            person, out, score = trial(params, cond, seed)
            for key, s in person.split.items():
                split[key] += s
            for stage in ("survey", "follow_up"):
                holds = [(h, d) for st, h, d in person.holds if st == stage]
                n[f"{stage} presses"] += len(holds)
                n[f"{stage} planned hold s"] += sum(h for h, _ in holds)
                n[f"{stage} held s"] += sum(d for _, d in holds)
            decisions = person.perceived.get("follow_up_decisions", ())
            n["spots re-palpated"] += len(decisions)
            for *_, v, _k in decisions:
                verdicts[v] += 1
            n["survey stopped early"] += int(bool(person.perceived.get("survey_stopped_early")))
            n["reports"] += score.reports
            n["false reports"] += score.false_reports
            n["found"] += score.nodules_found
            n["C found"] += int(any(m.found for m in score.per_nodule if m.nodule == "C"))
            n["duration s"] += out.duration_s
        k = float(seeds)
        print(f"== {cond} ({seeds} trials, seeds 100-{99 + seeds}, {' '.join(argv[2:]) or 'v5 means'}; "
              f"{time.process_time() - t0:.1f} s CPU)")
        for stage in ("survey", "follow_up"):
            parts = "  ".join(f"{ph} {split[(stage, ph)] / k:6.1f}" for ph in PHASES)
            total = sum(split[(stage, ph)] for ph in PHASES) / k
            presses = n[f"{stage} presses"]
            per = (f"; per press {total / (presses / k):.2f} s, planned hold "
                   f"{n[f'{stage} planned hold s'] / presses:.2f} s, held {n[f'{stage} held s'] / presses:.2f} s"
                   ) if presses else ""
            print(f"  {stage:9s} {total:6.1f} s = {parts}; {presses / k:5.1f} presses{per}")
        other = sum(s for (st, ph), s in split.items() if ph not in PHASES) / k
        print(f"  other (setup, decide, report) {other:.2f} s")
        print("  " + ", ".join(f"{key} {val / k:.2f}" for key, val in n.items() if "presses" not in key
                               and "hold" not in key and "held" not in key)
              + f"; verdicts {dict(verdicts)}; found total {int(n['found'])} of {3 * seeds}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
