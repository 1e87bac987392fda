"""What a practised seed-000 palpator does with what it learnt: bio-inspired feedback against none, trial by trial.

Usage: ``python scripts/palpation_practice_decision.py [TRIALS] [name=value ...]`` (default 24 trials per
controller; ~15 s CPU). ``name=value`` overrides a palpator parameter of the typical person, e.g.
``report_rule=odds``, ``confirm_rounds=3``, ``cue_learning=shrinkage`` or ``practice_presses=8``.

The person is the shipped population's typical one (every trait at its location) with ``familiarise`` on. Before
each trial it practises on the example phantom (the 3 marked sites) through the trial's controller, as the engine
runs it; the trial then goes through the real sponge scene, simulated forceps and controller at 50 Hz, with the
tumours at the broken-controller test's sites and seeds. Printed per controller: tumours found (a report within one
cell, the paper's rule) by class, wrong reports, how many trials reported a cell on evidence and how many fell back
to guessing (nothing passed the report criterion), and how well the learnt combination told each tumour class from
plain cells on its first press of the trial (d' = mean difference over the plain cells' SD, in the person's
combined-evidence units). Why: the ideal observer (``scripts/palpation_cue_dprime.py``) gives one bio-inspired press
about twice the no-feedback d', yet the practised person found no more tumours with it; this shows where it is lost.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from palpation.practice_support import found, trial_after_practice  # noqa: E402

from studyctl.controllers.bio_inspired import BioInspiredController  # noqa: E402
from studyctl.controllers.palpation import NoFeedback  # noqa: E402
from studyctl.models.grid_cells import within_one_cell  # noqa: E402
from studyctl.participants.palpator import VirtualPalpator  # noqa: E402
from studyctl.participants.palpator_params import PARAMS  # noqa: E402
from studyctl.populations import load_population_file, shipped_population_path  # noqa: E402


def typical_person(overrides: list[str]) -> dict:
    pop = load_population_file(shipped_population_path("bio_inspired_palpation"))
    params = dict(pop.params({t.name: t.value(0.0) for t in pop.traits}))
    params["familiarise"] = True
    defaults = {p.name: p.default for p in PARAMS}
    for item in overrides:
        name, value = item.split("=", 1)
        d = defaults[name]
        params[name] = (value == "true") if isinstance(d, bool) else type(d)(value)
    return params


def main(argv: list[str]) -> None:
    trials = int(argv[0]) if argv and "=" not in argv[0] else 24
    params = typical_person([a for a in argv if "=" in a])
    t0 = time.process_time()
    for controller_cls in (BioInspiredController, NoFeedback):
        by_class = {"soft": 0, "medium": 0, "hard": 0}
        wrong = on_evidence = guessed = 0
        first = {"soft": [], "medium": [], "hard": [], "plain": []}
        for k in range(trials):
            person = VirtualPalpator(params)
            out, scene = trial_after_practice(person, controller_cls, k)
            for cls, hit in found(out, scene).items():
                by_class[cls] += hit
            truth = {(t["col"], t["row"]): t["class"] for t in scene.truth()["tumours"]}
            # a wrong report: more than one cell from every tumour (the nearest one's distance is the minimum)
            wrong += sum(not any(within_one_cell((r["column"], r["row"]), c) for c in truth)
                         for r in out.reports)
            ref = person._ref or person._reference()
            evidence = [(person._score(ev, ref), person._level(ev)) for ev in person.evidence.values()]
            if any(score > level for score, level in evidence):
                on_evidence += 1
            else:
                guessed += 1
            if person.cues is None or person._ref_combined is None:
                continue
            for cell, ev in person.evidence.items():
                if not ev.combined:
                    continue
                z = (ev.combined[0] - person._ref_combined) / person.cues.spread
                if cell in truth:
                    first[truth[cell]].append(z)
                elif not any(within_one_cell(cell, c) for c in truth):
                    first["plain"].append(z)
        plain = np.array(first["plain"])
        dprime = {c: (np.mean(first[c]) - plain.mean()) / plain.std() if first[c] and plain.size > 1 else float("nan")
                  for c in ("soft", "medium", "hard")}
        print(f"{controller_cls.name:13s} found {sum(by_class.values()):2d}/{3 * trials} "
              f"(hard/medium/soft {by_class['hard']}/{by_class['medium']}/{by_class['soft']}), wrong reports {wrong}, "
              f"trials reported on evidence {on_evidence}, guessed {guessed}; first-press d' of the learnt "
              f"combination soft/medium/hard {dprime['soft']:.2f}/{dprime['medium']:.2f}/{dprime['hard']:.2f}")
    print(f"({time.process_time() - t0:.1f} s CPU)")


if __name__ == "__main__":
    from script_usage import argv_or_usage

    main(argv_or_usage(__doc__))
