"""How a practised seed-000 palpator decides to re-press, keep pressing or stop, per feedback condition.

Usage: ``python scripts/palpation_press_decisions.py [TRIALS] [name=value ...] [controllers=a,b]`` (default 24 trials
per controller, ~25 s CPU for the four). ``name=value`` overrides a palpator parameter of the typical person, as in
``scripts/palpation_contact_time.py``, whose logged trial this reuses (same person, scenes and seeds).

Printed per controller (the typical v5 person after practice, every trait at its location):

1. **presses per spot**: presses a trial on tumour cells (by class), on their 8 neighbours and on the other cells,
   and how many re-probe rounds ran;
2. **the decision after each round**: the share of tumour and of plain cells whose evidence was past the report
   level (decided), between ``screen_z`` and it (undecided: pressed again), or below ``screen_z`` (dismissed), after
   the sweep; and the share reported at the end;
3. **what each cue gives the decision**: the delivered balloon pressure at the press bottom (checkpoint 1) and at its
   peak, and the vibration's peak, median over tumour and plain presses (psi, m/s^2), and how much of a tumour
   press's combined evidence (the weights learnt in practice, in plain-press spreads) came from balloon notes,
   vibration notes and the camera;
4. **how long a contact lasts and why**: contact per tumour press (force > 0.5 N), its planned ramp in / hold /
   ramp out, and how presses ended (planned trapezoid, cue stop, looked on).

Why: the paper's bio-inspired subjects spent the least time on the tumours (median 1.9 s, linear 2.7, piecewise 2.5,
none 3.1 s) with the highest accuracy (0.83); v5's cohort spends 2.44 s with 0.67. Contact per trial is presses on
tumours x contact per press, and the press ends when its plan ends (``palpation_contact_time.py``), so what is left
to see is why a spot is pressed again.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

from palpation_contact_time import CONTROLLERS, logged_trial, press_rows  # noqa: E402
from palpation_practice_decision import typical_person  # noqa: E402

from studyctl.participants.palpator import VirtualPalpator  # noqa: E402
from studyctl.participants.palpator_perception import VISUAL  # noqa: E402

NOTES = (("balloon_psi", "1"), ("balloon_psi", "peak"), ("vibration_ms2", "peak"))  # delivered values kept per press


class _Watched(VirtualPalpator):
    """The person as is, keeping per press what was delivered and where its combined evidence came from, and per
    re-probe round each cell's state (decided, undecided, dismissed)."""

    def begin_trial(self, info, rng):
        super().begin_trial(info, rng)
        self.press_log: list[dict] = []
        self.rounds_log: list[dict[tuple[int, int], str]] = []
        self.guessed: list[tuple[int, int]] = []  # the cells reported when nothing passed the report level

    def _end_segment(self, seg):
        if seg.kind != "press" or self._practice:
            return super()._end_segment(seg)
        row = {"cell": seg.cell, "round": self._rounds}
        row.update({f"{ch} {n}": self._notes.get((ch, n), 0.0) for ch, n in NOTES})
        ev = self.evidence.get(seg.cell)
        before = {k: len(v) for k, v in ev.logs.items()} if ev is not None else {}
        super()._end_segment(seg)
        ev = self.evidence[seg.cell]
        share = {"balloon": 0.0, "vibration": 0.0, "camera": 0.0}
        if self.cues is not None and self.cues.spread > 0:
            for key, w, c in zip(self.cues.keys, self.cues.weights, self.cues.centres, strict=True):
                logs = ev.logs.get(key, [])
                if len(logs) > before.get(key, 0):  # noted on this press
                    part = "camera" if key == VISUAL else key[0].split("_")[0]
                    share[part] = share.get(part, 0.0) + w * (logs[-1] - c) / self.cues.spread
        row.update({f"from {k}": v for k, v in share.items()})
        self.press_log.append(row)

    def _queue_confirmations(self, first=True):
        super()._queue_confirmations(first)
        ref, screen = self._ref, self.params["screen_z"]
        state = {}
        for cell, ev in self.evidence.items():
            score = self._score(ev, ref)
            state[cell] = "decided" if score > self._level(ev) else "undecided" if score > screen else "dismissed"
        self.rounds_log.append(state)

    def _guess(self, scored):
        self.guessed = super()._guess(scored)
        return self.guessed


def _near(cell, sites) -> str:
    for (c, r), cls in sites.items():
        if cell == (c, r):
            return cls
    if any(max(abs(cell[0] - c), abs(cell[1] - r)) == 1 for c, r in sites):
        return "neighbour"
    return "other"


def run_controller(params: dict, cls, trials: int) -> dict[str, str]:
    t0 = time.process_time()
    presses, rounds, states, reported, contact, outcomes = [], [], [], [], [], []
    for k in range(trials):
        person = _Watched(params)
        samples, cues, logged, truth, reports = logged_trial(params, cls, k, person=person)
        sites = {(t["col"], t["row"]): t["class"] for t in truth["tumours"]}
        rows, _ = press_rows(samples, cues, logged, truth)
        for watched, timed, seg in zip(person.press_log, rows, logged, strict=True):
            presses.append({**watched, **timed, "k": k, "spot": _near(seg["cell"], sites)})
        rounds.append(len(person.rounds_log))
        if person.rounds_log:
            for cell, state in person.rounds_log[0].items():
                states.append({"spot": _near(cell, sites), "state": state})
        got = {(r["column"], r["row"]) for r in reports}
        for cell in got:
            right = any(max(abs(cell[0] - c), abs(cell[1] - r)) <= 1 for c, r in sites)
            outcomes.append(("guess" if cell in person.guessed else "evidence", right))
        reported += [{"spot": _near(cell, sites), "reported": cell in got} for cell in person.evidence]
        contact.append(person.params["depth_mm"] / person.params["press_speed_mm_s"])
    df, st, rep = pd.DataFrame(presses), pd.DataFrame(states), pd.DataFrame(reported)
    per_trial = df.groupby("spot").size() / trials
    tumour = df[df["spot"].isin(("soft", "medium", "hard"))]
    plain = df[df["spot"] == "other"]
    sweep_tumour = tumour[tumour["round"] == 0]
    out = {"controller": cls.name}
    out["presses/trial on the soft/medium/hard cell"] = "/".join(
        f"{per_trial.get(c, 0.0):.2f}" for c in ("soft", "medium", "hard"))
    out["presses/trial neighbour/other"] = f"{per_trial.get('neighbour', 0):.2f}/{per_trial.get('other', 0):.2f}"
    out["re-probe rounds/trial"] = f"{np.mean(rounds):.2f}"
    for spot in ("tumour", "other"):
        rows = st[st["spot"].isin(("soft", "medium", "hard"))] if spot == "tumour" else st[st["spot"] == spot]
        share = rows["state"].value_counts(normalize=True)
        out[f"after sweep, {spot}: decided/undecided/dismissed"] = "/".join(
            f"{share.get(s, 0.0):.2f}" for s in ("decided", "undecided", "dismissed"))
    for spot in ("soft", "medium", "hard", "other"):
        out[f"{spot} cell reported (share)"] = f"{rep[rep['spot'] == spot]['reported'].mean():.2f}"
    for how in ("evidence", "guess"):
        made = [right for kind, right in outcomes if kind == how]
        out[f"reports on {how}/trial: right/wrong"] = f"{sum(made) / trials:.2f}/{(len(made) - sum(made)) / trials:.2f}"
    per = [right for _, right in outcomes]
    out["accuracy (all reports)"] = f"{np.mean(per):.3f}" if per else "nan"
    for ch, n in NOTES:
        key = f"{ch} {n}"
        out[f"{key} tumour/plain (median)"] = f"{sweep_tumour[key].median():.2f}/{plain[key].median():.2f}"
    for part in ("balloon", "vibration", "camera"):
        out[f"evidence from {part}: tumour/plain press"] = (f"{tumour[f'from {part}'].mean():+.2f}/"
                                                            f"{plain[f'from {part}'].mean():+.2f}")
    out["contact per tumour press s"] = f"{tumour['tumour_contact_s'].mean():.3f}"
    ramp = float(np.mean(contact))
    out["planned ramp in / hold / ramp out s"] = f"{ramp:.3f} / {params['hold_s']:.3f} / {ramp:.3f}"
    ended = tumour["ended"].value_counts()
    out["tumour presses ended planned/cue stop/looked/settled"] = "/".join(
        str(int(ended.get(e, 0))) for e in ("planned", "cue stop", "looked", "settled"))
    out["CPU s"] = f"{time.process_time() - t0:.1f}"
    return out


def main(argv: list[str]) -> None:
    trials = int(argv[0]) if argv and "=" not in argv[0] else 24
    options = dict(a.split("=", 1) for a in argv if a.startswith("controllers="))
    overrides = [a for a in argv if "=" in a and not a.startswith("controllers=")]
    params = typical_person(overrides)
    wanted = options.get("controllers", ",".join(c.name for c in CONTROLLERS)).split(",")
    print(f"typical v5 person after practice, trials 0-{trials - 1} per controller; overrides: {overrides or 'none'}")
    table = [run_controller(params, cls, trials) for cls in CONTROLLERS if cls.name in wanted]
    with pd.option_context("display.width", 250, "display.max_columns", 30, "display.max_colwidth", 40):
        print(pd.DataFrame(table).set_index("controller").T.to_string())


if __name__ == "__main__":
    from script_usage import argv_or_usage

    main(argv_or_usage(__doc__))
