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

import math
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
# the press descent split where the watched point (cursor, else hand) is: above the visible surface or in the tissue
PRESS_PARTS = ("press in air", "press in tissue")


class Watched(VirtualTissuePalpator):
    """The same person, its ticks booked to (stage, phase) and each press's hold noted; it decides as before."""

    def begin_trial(self, info, rng):
        super().begin_trial(info, rng)
        self.split: dict[tuple[str, str], float] = defaultdict(float)
        self.holds: list[tuple[str, float, float]] = []  # stage, planned hold, time held
        # each press's descent: stage, time to the wanted depth, ended by the phase timeout, the push felt then
        self.descents: list[tuple[str, float, bool, float]] = []
        self._part = "setup"

    def act(self, t, percept):
        # the tick's time belongs to the phase (and press part) the person was in since its last tick
        dt = max(t - self._t_prev, 0.0)
        stage = getattr(self, "_stage", "setup")
        self.split[(stage, self._phase)] += dt
        self.split[(stage, self._part)] += dt
        phase, phase_t = self._phase, self._phase_t
        out = super().act(t, percept)
        if phase == "press" and self._phase != "press":
            force = math.sqrt(sum(float(percept.get(k, 0.0)) ** 2 for k in ("fx_n", "fy_n", "fz_n")))
            timeout = phase_t + self._dt >= self.params["phase_timeout_s"]
            self.descents.append((stage, phase_t + self._dt, timeout, force))
        self._part = self._press_part(percept) if self._phase == "press" else ""
        return out

    def _press_part(self, percept) -> str:
        view = percept.get("view") or {}
        watched = view.get("cursor_mm") or (percept.get("x_mm"), percept.get("y_mm"), percept.get("z_mm"))
        if watched[2] is None:
            watched = self._hand
        return PRESS_PARTS[0] if float(watched[2]) > self._press["h"] else PRESS_PARTS[1]

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
        all_descents: list[tuple[str, float, bool, float]] = []
        yields: list[float] = []
        for seed in range(100, 100 + seeds):
            person, out, score = trial(params, cond, seed)
            all_descents += person.descents
            yields.append(person._press_yield)
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
            descents = [(d, to, f) for st, d, to, f in all_descents if st == stage]
            if descents:
                air, tissue = (split[(stage, part)] / k for part in PRESS_PARTS)
                print(f"  {'':9s} press = in air {air:5.1f} + in tissue {tissue:5.1f} s; per descent "
                      f"{sum(d for d, _, _ in descents) / len(descents):.2f} s, ended by the phase timeout "
                      f"{sum(to for _, to, _ in descents) / len(descents):.0%}"
                      f", push felt at the bottom {sum(f for *_, f in descents) / len(descents):.2f} N; learnt press "
                      f"yield at the trial's end {sum(yields) / len(yields):.2f}")
        other = sum(s for (st, ph), s in split.items() if ph not in PHASES + PRESS_PARTS + ("",)) / k
        print(f"  other (setup, decide, report) {other:.2f} s")
        print("  " + ", ".join(f"{key} {val / k:.2f}" for key, val in n.items() if "presses" not in key
                               and "hold" not in key and "held" not in key)
              + f"; verdicts {dict(verdicts)}; found total {int(n['found'])} of {3 * seeds}", flush=True)


if __name__ == "__main__":
    from script_usage import argv_or_usage

    main(argv_or_usage(__doc__))
