"""How a seed-003 tissue palpator's slid survey adds its cues, in the trial loop: nodules found under Table 1.

Usage: ``python scripts/tissue_slide_fusion.py SEQUENCE SEEDS [name=value ...]``, e.g. ``PHF,PHF_FF 32
slide_survey=True slide_fusion=pooled cue_excess=stiffer`` (~35 s CPU for 32 pairs).

The person is the shipped population's typical one (every trait at its location, the fixed values) with the
overrides. Per seed (100, 101, ...) one person does the trials of SEQUENCE in order (conditions PHF, FF, PHF_FF; the
block turned a quarter turn per trial), so what it learnt in one trial carries into the next, as in a session; each
trial goes through the seed-003 block scene, the simulated Omni-class device and the condition's controller with
Table 1's sideways slowing (``lateral_ratio: normal`` on PHF and PHF_FF) at 250 Hz. Printed: nodules found in the
LAST trial of the sequence over all seeds (a report within the protocol's 10 mm), its mean duration, and the median
and interquartile range of the push's weight over the slowing's in that trial's slid survey (slide_fusion
reliability or pooled). Why: stop 29's per-trial reliability weights were mostly noise; this measures the pooled ones.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import yaml

from studyctl.controllers.tissue import PseudoHaptic, PseudoHapticForceFeedback, StiffnessMapForceFeedback
from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.models.palpation_metrics import score_trial
from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes.tissue import StiffnessTissueScene

CONTROLLERS = {"PHF": PseudoHaptic, "FF": StiffnessMapForceFeedback, "PHF_FF": PseudoHapticForceFeedback}
POPULATION = Path(__file__).resolve().parents[1] / "studyctl" / "populations" / "pseudo_haptic_palpation.yaml"


def typical_person(overrides: list[str]) -> dict:
    pop = yaml.safe_load(POPULATION.read_text())
    person = {k: v["mean"] for k, v in pop["traits"].items()}
    person.update(pop["fixed"])
    for item in overrides:
        key, value = item.split("=", 1)
        person[key] = yaml.safe_load(value)
    return person


def trial(person: VirtualTissuePalpator, cond: str, seed: int, k: int) -> tuple[int, float]:
    cls = CONTROLLERS[cond]
    scene = StiffnessTissueScene.build({"phantom": "seed003_block"}, {"orientation_deg": float(90 * k)},
                                       cls.needs({}) | {"view"}, np.random.default_rng(seed))
    device = SimulatedForceDevice({}, scene, np.random.default_rng(seed + 1))
    device.open()
    info = TrialInfo(condition=cond, time_limit_s=900.0, rate_hz=250.0, visual="realtime",
                     public={**scene.public(), "trial_index": k + 1})
    controller = cls({} if cond == "FF" else {"lateral_ratio": "normal"}, scene)
    out = run_trial(info=info, controller=controller, device=device, participant=person, clock=SimulatedClock(),
                    rng=np.random.default_rng(seed + 2 + 1000 * k), view=scene.view)
    device.close()
    score = score_trial(out.reports, scene.truth()["nodules"], hit_radius_mm=10.0, duration_s=out.duration_s)
    return score.nodules_found, out.duration_s


def main(argv: list[str]) -> None:
    sequence, seeds = argv[0].split(","), int(argv[1])
    params = typical_person(argv[2:])
    found, durations, ratios = 0, [], []
    t0 = time.process_time()
    for seed in range(100, 100 + seeds):
        person = VirtualTissuePalpator(params)
        for k, cond in enumerate(sequence):
            n, duration = trial(person, cond, seed, k)
        found += n
        durations.append(duration)
        weights = person._slide_weights
        if weights and "force" in weights and "cursor" in weights:
            ratios.append(weights["force"] / weights["cursor"])
    spread = (f"push/slowing weight median {np.median(ratios):.3f} IQR {np.percentile(ratios, 25):.3f}-"
              f"{np.percentile(ratios, 75):.3f}" if ratios else "no weights (equal weights or one cue)")
    print(f"{argv[0]} {' '.join(argv[2:])}: found {found} of {3 * seeds}, mean duration {np.mean(durations):.1f} s, "
          f"{spread}; {time.process_time() - t0:.1f} s CPU")


if __name__ == "__main__":
    from script_usage import argv_or_usage

    main(argv_or_usage(__doc__))
