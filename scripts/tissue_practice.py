"""What seed 003's practice run with visible nodules does for a tissue palpator, in the trial loop.

Usage: ``python scripts/tissue_practice.py CONDITIONS SEEDS [name=value ...]``, e.g. ``PHF,FF,PHF_FF 32``
(add ``table1=True`` for Table 1's sideways slowing on PHF and PHF_FF, the shipped protocol being equation 3;
``practice=weights`` for the learnt cue weights alone, default ``learn``; ``arms=practised`` to run only the
practised arm, the unpractised one being the same at the same seeds).

The person is the shipped population's typical one (every trait at its location, the fixed values) with the
overrides. Per condition and seed (100, 101, ...) a fresh person does the condition's test trial (the block turned a
quarter turn) twice: once without practice, and once after that condition's practice block (orientation 0, its
nodules shown as marks) with ``practice: learn``; the test trial's scene, device and person streams are the same in
both arms (common random numbers). Each trial goes through the seed-003 block scene, the simulated Omni-class device
and the condition's controller at 250 Hz. Printed per condition and arm: nodules found (a report within the
protocol's 10 mm) of 3 per seed, nodule C found, reports made, mean test duration, and for the practised arm the
median learnt cue excesses and weights. Why: stop 30 left the practice unbuilt; this measures it before a cohort.
"""

from __future__ import annotations

import time

import numpy as np
from tissue_slide_fusion import CONTROLLERS, typical_person

from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.models.palpation_metrics import score_trial
from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.participants.tissue_practice import trust
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes.tissue import StiffnessTissueScene


def run(person: VirtualTissuePalpator, cond: str, seed: int, orientation: float, practice: bool, table1: bool):
    cls = CONTROLLERS[cond]
    scene = StiffnessTissueScene.build({"phantom": "seed003_block"}, {"orientation_deg": orientation},
                                       cls.needs({}) | {"view"}, np.random.default_rng(seed + (7 if practice else 0)))
    device = SimulatedForceDevice({}, scene, np.random.default_rng(seed + (8 if practice else 1)))
    device.open()
    public = {**scene.public(), "trial_index": 1}
    if practice:
        public.update(practice=True, marks=list(scene.marks()))
    info = TrialInfo(condition=cond, time_limit_s=300.0 if practice else 900.0, rate_hz=250.0, visual="realtime",
                     public=public)
    controller = cls({"lateral_ratio": "normal"} if table1 and cond != "FF" else {}, scene)
    out = run_trial(info=info, controller=controller, device=device, participant=person, clock=SimulatedClock(),
                    rng=np.random.default_rng(seed + (9 if practice else 2)), view=scene.view)
    device.close()
    return out, scene


def main(argv: list[str]) -> None:
    conds, seeds = argv[0].split(","), int(argv[1])
    overrides = [a for a in argv[2:] if not a.startswith(("table1=", "practice=", "arms="))]
    mode = next((a.split("=", 1)[1] for a in argv[2:] if a.startswith("practice=")), "learn")
    table1 = any(a == "table1=True" for a in argv[2:])
    for cond in conds:
        for practise in ((True,) if "arms=practised" in argv else (False, True)):
            params = typical_person(overrides + [f"practice={mode if practise else 'none'}"])
            found = c_found = reports = 0
            durations, excess, faint, weights, practice_s = [], {}, {}, {}, []
            t0 = time.process_time()
            for seed in range(100, 100 + seeds):
                person = VirtualTissuePalpator(params)
                if practise:
                    out, _ = run(person, cond, seed, 0.0, True, table1)
                    practice_s.append(out.duration_s)
                    learnt = person.learnt.get(cond) or {}
                    for name, c in learnt.items():
                        excess.setdefault(name, []).append(c["excess"] / c["sd"])
                        faint.setdefault(name, []).append(c["faintest"] / c["sd"])
                    for name, w in (trust(learnt) or {}).items():
                        weights.setdefault(name, []).append(w)
                out, scene = run(person, cond, seed, 90.0, False, table1)
                nodules = scene.truth()["nodules"]
                score = score_trial(out.reports, nodules, hit_radius_mm=10.0, duration_s=out.duration_s)
                found += score.nodules_found
                reports += len(out.reports)
                c = next(n for n in nodules if n["name"] == "C")
                c_found += int(any(np.hypot(r["x_mm"] - c["x_mm"], r["y_mm"] - c["y_mm"]) <= 10.0 for r in out.reports))
                durations.append(out.duration_s)
            learnt_txt = ""
            if practise:
                med = {k: round(float(np.median(v)), 2) for k, v in excess.items()}
                wmed = {k: round(float(np.median(v)), 2) for k, v in weights.items()}
                fmed = {k: round(float(np.median(v)), 2) for k, v in faint.items()}
                learnt_txt = (f"; practice {np.mean(practice_s):.1f} s; excess/sd median {med}, faintest {fmed}; "
                              f"weight median {wmed}")
            print(f"{cond} practice={mode if practise else 'none'} {' '.join(argv[2:])}: found {found} of "
                  f"{3 * seeds} (C {c_found}), reports {reports}, mean duration {np.mean(durations):.1f} s"
                  f"{learnt_txt}; {time.process_time() - t0:.1f} s CPU", flush=True)


if __name__ == "__main__":
    from script_usage import argv_or_usage

    main(argv_or_usage(__doc__))
