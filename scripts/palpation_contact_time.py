"""Why a seed-000 virtual palpator's presses last as long as they do, per feedback controller, press by press.

Usage: ``python scripts/palpation_contact_time.py [TRIALS] [name=value ...] [controllers=a,b] [first=K]`` (default
24 trials per controller, trials 0-23, ~22 s CPU for the four). ``name=value`` overrides a palpator parameter of the
typical person (as in ``scripts/palpation_practice_decision.py``), e.g. ``lift_rule=settled`` or ``sure_odds=19``.

The person is the shipped population's typical one (every trait at its location, ``familiarise`` on), trial ``k`` of
each controller the same scene, tumour sites and seeds as the broken-controller tests (``practice_support``). Every
press of the trial is logged with the engine's samples and what the device delivered to the finger. Printed per
controller:

1. the paper's metric, tumour contact time per trial (force > 0.5 N with the probe footprint over a tumour, the
   report's own ``tumour_contact_mask``): median and IQR over the trials, and how it splits into presses that
   touched a tumour x contact per such press; sweep and re-probe presses apart;
2. per press that touched a tumour: its contact time (force > 0.5 N), peak force, how the press ended (the planned
   trapezoid ran out, a cue stopped the descent, or the person looked on because nothing was felt), the time from
   contact to the first change of the delivered cue by one Weber step of the person (balloon 10 %, vibration 20 %)
   after the cue's first value, to the last such change (the cue has stopped changing), to the force passing the
   bio-inspired model's F_crit (2.115 N: the CAPR disc is pressed past its height, the only place its feedback grades
   tumours, ``palpation_stimulus_chain.py``), and to the lift (force back under 0.5 N).

Why: the paper's bio-inspired subjects spent the least time on the tumours (median 1.9 s against linear 2.7,
piecewise 2.5, none 3.1 s; Results III.B) and its discussion credits the vibration felt in the dynamic phase of the
press; the simulated people spend more with bio-inspired than with linear feedback. This shows what the lift waited
for.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from palpation.practice_support import trial_after_practice  # noqa: E402
from palpation_practice_decision import typical_person  # noqa: E402

from studyctl.analysis.metrics import tumour_contact_mask  # noqa: E402
from studyctl.controllers.bio_inspired import BioInspiredController  # noqa: E402
from studyctl.controllers.palpation import LinearController, NoFeedback, PiecewiseController  # noqa: E402
from studyctl.models.grid_cells import within_one_cell  # noqa: E402
from studyctl.participants.palpator import VirtualPalpator  # noqa: E402

THRESHOLD_N = 0.5  # the analysis plan's contact threshold (metrics.tumour_contact_time default)
F_CRIT_N = 2.115  # the bio-inspired CAPR disc's height is reached (studyctl/models/capr_skin.py)
WEBER = {"balloon_psi": 0.10, "vibration_ms2": 0.20}  # the typical person's Weber fractions (population means)
CONTROLLERS = (NoFeedback, PiecewiseController, LinearController, BioInspiredController)


def logged_trial(params: dict, controller_cls, k: int, person: VirtualPalpator | None = None):
    """Run trial ``k`` and return its samples (with the delivered cues), its presses and its scene's truth. A caller
    that watches the person's own state passes its ``person`` (built from ``params``)."""
    person = VirtualPalpator(params) if person is None else person
    presses: list[dict] = []
    feel: list[tuple[float, float, float]] = []
    rows: list[tuple[float, float, float, float]] = []
    act, end = person.act, person._end_segment

    def logged_act(t, percept):
        if not person._practice:
            feel.append((t, float(percept.get("balloon_psi") or 0.0), float(percept.get("vibration_ms2") or 0.0)))
        return act(t, percept)

    def logged_end(seg):
        if not person._practice and seg.kind == "press":
            presses.append({"t0": person._seg_t0, "t1": person._seg_t0 + seg.duration, "cell": seg.cell,
                            "stopped": seg.stopped, "phase": person._phase,
                            "lift": seg.lift, "held": seg.held})
        return end(seg)

    queue = person._queue_confirmations
    decided: dict = {}  # after the sweep: the re-probed cells whose evidence already passed the report level

    def logged_queue(first=True):
        queue(first)
        if first:
            ref = person._ref
            for cell, ev in person.evidence.items():
                score = person._score(ev, ref)
                if score > person.params["screen_z"]:
                    decided[cell] = score > person._level(ev)

    person.act, person._end_segment, person._queue_confirmations = logged_act, logged_end, logged_queue

    def on_sample(t, sample):
        rows.append((t, sample["force_n"], sample["probe_x_mm"], sample["probe_y_mm"]))

    out, scene = trial_after_practice(person, controller_cls, k, on_sample=on_sample)
    samples = pd.DataFrame(rows, columns=["t", "force_n", "probe_x_mm", "probe_y_mm"])
    cues = pd.DataFrame(feel, columns=["t", "balloon_psi", "vibration_ms2"])
    for p in presses:
        p["decided"] = decided.get(p["cell"])
    return samples, cues, presses, scene.truth(), list(out.reports)


def first_last_change(cue: np.ndarray, weber: float) -> tuple[int | None, int | None]:
    """Indices of the first and the last change of a cue by one Weber step from the value it held before."""
    first = last = None
    ref = cue[0]
    for i in range(1, len(cue)):
        if abs(cue[i] - ref) > weber * max(abs(ref), 1e-9) and max(cue[i], ref) > 1e-6:
            first = i if first is None else first
            last = i
            ref = cue[i]
    return first, last


def press_rows(samples, cues, presses, truth):
    t = samples["t"].to_numpy()
    f = samples["force_n"].to_numpy()
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2]))
    on_tumour = tumour_contact_mask(samples, truth, THRESHOLD_N)
    ct = cues["t"].to_numpy()
    out = []
    for p in presses:
        w = (t >= p["t0"]) & (t < p["t1"])
        contact = w & (f > THRESHOLD_N)
        tumour_s = float(dt[w & on_tumour].sum())
        row = {"phase": p["phase"], "tumour": tumour_s > 0, "tumour_contact_s": tumour_s,
               "contact_s": float(dt[contact].sum()), "peak_n": float(f[w].max()) if w.any() else 0.0,
               "ended": "cue stop" if p["stopped"] else p["lift"], "held_s": p["held"], "decided": p["decided"]}
        if contact.any():
            idx = np.flatnonzero(contact)
            on, off = t[idx[0]], t[idx[-1]] + dt[idx[-1]]
            row["lift_s"] = off - on
            crit = np.flatnonzero(w & (f > F_CRIT_N))
            top = t[w][np.argmax(f[w])]
            row["to_fcrit_s"] = t[crit[0]] - on if crit.size else np.nan
            cw = (ct >= on) & (ct < off)
            for ch, weber in WEBER.items():
                series = cues[ch].to_numpy()[cw]
                first, last = first_last_change(series, weber) if series.size > 1 else (None, None)
                row[f"{ch}_first_s"] = ct[cw][first] - on if first is not None else np.nan
                row[f"{ch}_last_s"] = ct[cw][last] - on if last is not None else np.nan
                # when the cue was strongest, against the bottom of the press (negative: it peaked on the way in)
                row[f"{ch}_peak_s"] = ct[cw][int(np.argmax(series))] - top if series.size and series.max() > 0 \
                    else np.nan
        out.append(row)
    return out, float(dt[on_tumour].sum())


def main(argv: list[str]) -> None:
    trials = int(argv[0]) if argv and "=" not in argv[0] else 24
    options = dict(a.split("=", 1) for a in argv if a.startswith(("controllers=", "first=")))
    overrides = [a for a in argv if "=" in a and not a.startswith(("controllers=", "first="))]
    params = typical_person(overrides)
    first = int(options.get("first", 0))
    wanted = options.get("controllers", ",".join(c.name for c in CONTROLLERS)).split(",")
    print(f"typical v5 person, trials {first}-{first + trials - 1} per controller; overrides: {overrides or 'none'}")
    tables = []
    for cls in (c for c in CONTROLLERS if c.name in wanted):
        t0 = time.process_time()
        per_trial, rows, scores = [], [], []
        for k in range(first, first + trials):
            samples, cues, presses, truth, reports = logged_trial(params, cls, k)
            pr, total = press_rows(samples, cues, presses, truth)
            sites = [(t["col"], t["row"]) for t in truth["tumours"]]
            right = [any(within_one_cell((r["column"], r["row"]), c) for c in sites) for r in reports]
            hits = [any(within_one_cell((r["column"], r["row"]), c) for r in reports) for c in sites]
            scores.append((sum(hits), len(right) - sum(right), sum(right) / len(right) if right else np.nan))
            per_trial.append((total, sum(r["tumour"] for r in pr),
                              sum(r["tumour"] and r["phase"] != "sweep" for r in pr)))
            rows += pr
        df = pd.DataFrame(rows)
        ct = np.array([p[0] for p in per_trial])
        q1, med, q3 = np.percentile(ct, [25, 50, 75])
        tum = df[df["tumour"]]
        ended = tum["ended"].value_counts()
        redone = tum["phase"] != "sweep"
        tables.append({
            "controller": cls.name,
            "contact s/trial med (IQR)": f"{med:.2f} ({q1:.2f}-{q3:.2f})",
            "tumour presses/trial": f"{np.mean([p[1] for p in per_trial]):.2f}",
            "of them re-probes": f"{np.mean([p[2] for p in per_trial]):.2f}",
            "tumour s/press": f"{tum['tumour_contact_s'].mean():.3f}",
            "all presses s": f"{df['contact_s'].mean():.3f}",
            "peak N (tumour)": f"{tum['peak_n'].median():.2f}",
            "ended planned/cue stop/looked/settled": "/".join(str(int(ended.get(e, 0))) for e in (
                "planned", "cue stop", "looked", "settled")),
            "held for a rising cue s (mean)": f"{tum['held_s'].mean():.3f}",
            "to F_crit s": f"{tum['to_fcrit_s'].median():.3f} ({tum['to_fcrit_s'].notna().mean():.0%})",
            "balloon 1st/last s": f"{tum['balloon_psi_first_s'].median():.3f}/{tum['balloon_psi_last_s'].median():.3f}",
            "vib 1st/last s": f"{tum['vibration_ms2_first_s'].median():.3f}/"
                              f"{tum['vibration_ms2_last_s'].median():.3f}",
            "cue peak - press bottom s (balloon/vib)": f"{tum['balloon_psi_peak_s'].median():.3f}/"
                                                        f"{tum['vibration_ms2_peak_s'].median():.3f}",
            "lift s": f"{tum['lift_s'].median():.3f}",
            "re-probes of decided tumours/trial": f"{(redone & (tum['decided'] == True)).sum() / trials:.2f}",  # noqa: E712
            "found / wrong reports": f"{sum(x[0] for x in scores)}/{3 * trials} / {sum(x[1] for x in scores)}",
            "accuracy median (mean)": f"{np.nanmedian([x[2] for x in scores]):.2f} "
                                      f"({np.nanmean([x[2] for x in scores]):.3f})",
            "CPU s": f"{time.process_time() - t0:.1f}",
        })
    with pd.option_context("display.width", 250, "display.max_columns", 30):
        print(pd.DataFrame(tables).set_index("controller").T.to_string())


if __name__ == "__main__":
    from script_usage import argv_or_usage

    main(argv_or_usage(__doc__))
