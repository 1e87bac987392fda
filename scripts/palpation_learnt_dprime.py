"""How well what practice teaches tells each tumour class from sponge, by learner and by how many practice presses.

Usage: ``python scripts/palpation_learnt_dprime.py [TRIALS] [name=value ...]`` (default 24 per controller; ~25 s
CPU); ``name=value`` overrides a palpator parameter of the typical person, e.g. ``practice_rule=until_learnt``.

The shipped population's typical person (``palpation_practice_decision.py``'s) practises on the example phantom and then
palpates, TRIALS times per controller (the broken-controller test's sites and seeds). Kept: every practice press's
log-notes (on each mark, and on plain sponge) and, in each trial, each cell's first press. Each learner of
:mod:`studyctl.participants.palpator_practice` (``diagonal``, ``by_mark``, ``shrinkage``) is then fitted on the presses
of one practice (what a person has: 3 marks x 4 presses and 12 plain), of m practices pooled (m x as many presses, as if
the person had pressed m times as long), and of all TRIALS practices at once (a learner with little sampling noise), and
judged on the trials' first presses: d' per class = mean minus plain cells' mean over their SD, each trial's evidence
centred on its median cell (as the person's reference). Why: v5's learnt d' on soft tumours (0.09) sat far below the
ideal observer's (0.69, ``palpation_cue_dprime.py``); this separates the learner's form from the number of presses it
learns from.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from palpation.practice_support import trial_after_practice  # noqa: E402
from palpation_practice_decision import typical_person  # noqa: E402

from studyctl.controllers.bio_inspired import BioInspiredController  # noqa: E402
from studyctl.controllers.palpation import LinearController, NoFeedback, PiecewiseController  # noqa: E402
from studyctl.models.grid_cells import within_one_cell  # noqa: E402
from studyctl.participants.palpator import VirtualPalpator  # noqa: E402
from studyctl.participants.palpator_practice import learn_cue_weights  # noqa: E402

CLASSES = ("soft", "medium", "hard")


def capture(controller_cls, trials: int, params: dict) -> list[dict]:
    """Per trial: the practice presses (on a mark or plain), the senses' noise floor, the trial's first presses."""
    rows = []
    for k in range(trials):
        person = VirtualPalpator(params)
        kept = {}

        def keep(p, example, kept=kept):
            marked = {(m["col"], m["row"]) for m in example.marks()}
            kept["tumour"] = [logs for cell, logs in p._press_logs if cell in marked]
            kept["marks"] = [cell for cell, _ in p._press_logs if cell in marked]
            kept["plain"] = [logs for cell, logs in p._press_logs if cell not in marked]

        _, scene = trial_after_practice(person, controller_cls, k, after_practice=keep)
        floor = {ch: sense.sigma**2 for ch, sense in person.senses.items()}
        floor["view"] = person.senses["view"].sigma ** 2
        truth = {(t["col"], t["row"]): t["class"] for t in scene.truth()["tumours"]}
        first = {cell: ev.first for cell, ev in person.evidence.items() if ev.first is not None}
        rows.append({**kept, "floor": floor, "truth": truth, "first": first})
    return rows


def dprime(rows: list[dict], learnt) -> dict[str, float]:
    """First-press d' per class of the combinations ``learnt(i)`` (one per trial i)."""
    z = {c: [] for c in (*CLASSES, "plain")}
    for i, r in enumerate(rows):
        cues = learnt(i)
        if cues is None:
            continue
        scores = {cell: v for cell, p in r["first"].items() if (v := cues.combine(p)) is not None}
        if not scores:
            continue
        centre = float(np.median(list(scores.values())))
        for cell, v in scores.items():
            if cell in r["truth"]:
                z[r["truth"][cell]].append((v - centre) / cues.spread)
            elif not any(within_one_cell(cell, c) for c in r["truth"]):
                z["plain"].append((v - centre) / cues.spread)
    plain = np.array(z["plain"])
    return {c: (np.mean(z[c]) - plain.mean()) / plain.std() if z[c] and plain.size > 1 else float("nan")
            for c in CLASSES}


def main(argv: list[str]) -> None:
    trials = int(argv[0]) if argv and "=" not in argv[0] else 24
    params = typical_person([a for a in argv if "=" in a])
    t0 = time.process_time()
    for controller_cls in (BioInspiredController, NoFeedback, LinearController, PiecewiseController):
        rows = capture(controller_cls, trials, params)
        print(controller_cls.name)
        for m in (1, 2, 3, 5, trials):
            for rule in ("diagonal", "by_mark", "shrinkage"):
                def learnt(i, m=m, rule=rule, rows=rows):
                    pooled = [rows[(i + j) % len(rows)] for j in range(m)]
                    tumour = [p for r in pooled for p in r.get("tumour", [])]
                    marks = [c for r in pooled for c in r.get("marks", [])]  # every practice marks the same cells
                    plain = [p for r in pooled for p in r.get("plain", [])]
                    return learn_cue_weights(tumour, plain, rows[i]["floor"], 3 / 49, rule, marks)

                d = dprime(rows, learnt)
                label = "all practices" if m == trials else f"{m} practice{'s' if m > 1 else ''}"
                print(f"  {label:14s} {rule:9s} first-press d' soft/medium/hard "
                      f"{d['soft']:.2f}/{d['medium']:.2f}/{d['hard']:.2f}")
    print(f"({time.process_time() - t0:.1f} s CPU)")


if __name__ == "__main__":
    from script_usage import argv_or_usage

    main(argv_or_usage(__doc__))
