"""Peak force of every press in a simulated (or real) seed-000 study, by condition and by what was under the probe.

Usage: ``python scripts/palpation_press_forces.py WORKSPACE/study.db [F_CRIT_N]`` (F_CRIT_N default 2.115, the
bio-inspired controller's CAPR sensor disc pressed past its height; see ``palpation_stimulus_chain.py``).

A press is a run of recorded samples with force above 0.2 N (the BHF analysis's mean-force floor); its spot is the
tumour whose footprint the probe overlaps at the press's peak (``tumour_under_probe``, the contact metrics' rule),
else sponge. Printed per condition and spot: presses, median and IQR of the peak force, and the share of presses
whose peak passes F_CRIT_N. It says in which regime of the controllers' maps (section 4 of
``palpation_stimulus_chain.py``) the presses of a study actually were.

Then, per condition, what the study's tumour contact time (the report's ``tumour_contact_mask``: force > 0.5 N with
the probe over a tumour) is made of: its median per trial, the presses that touched a tumour per trial and the
contact per such press (``palpation_contact_time.py`` shows it press by press for one typical person).
"""

from __future__ import annotations

import sys

import numpy as np
from sqlalchemy import select

from studyctl.analysis.metrics import tumour_contact_mask
from studyctl.scenes.sponge import SpongePhantomScene, tumour_under_probe
from studyctl.store.db import Database
from studyctl.store.models import Trial
from studyctl.store.samples import read_samples

PRESS_FLOOR_N = 0.2
SPOTS = ("sponge", "soft", "medium", "hard")


def press_peaks(force: np.ndarray) -> list[int]:
    """Index of the peak of each run of samples above the floor."""
    on = np.concatenate(([False], force > PRESS_FLOOR_N, [False]))
    edges = np.flatnonzero(np.diff(on.astype(np.int8)))
    return [int(a + np.argmax(force[a:b])) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def main(path: str, f_crit: float) -> None:
    db = Database.open(path)
    with db.reading() as s:
        trials = s.execute(select(Trial.id, Trial.condition, Trial.placement)).all()
    peaks: dict[str, dict[str, list[float]]] = {}
    contact: dict[str, list[tuple[float, int]]] = {}  # per trial: tumour contact s, presses that touched a tumour
    for trial_id, condition, placement in trials:
        frame = read_samples(db, trial_id)
        if frame.empty or "force_n" not in frame:
            continue
        truth = SpongePhantomScene.build({}, placement or {}, frozenset(), np.random.default_rng(0)).truth()
        f, x, y = (frame[c].to_numpy() for c in ("force_n", "probe_x_mm", "probe_y_mm"))
        for k in press_peaks(f):
            spot = tumour_under_probe(truth, float(x[k]), float(y[k])) or "sponge"
            peaks.setdefault(condition, {}).setdefault(spot, []).append(float(f[k]))
        t = frame["t"].to_numpy()
        dt = np.diff(t, append=t[-1] + (t[-1] - t[-2] if len(t) > 1 else 0.0))
        touching = tumour_contact_mask(frame, truth, 0.5)
        on = np.concatenate(([False], f > PRESS_FLOOR_N, [False]))
        edges = np.flatnonzero(np.diff(on.astype(np.int8)))
        touched = sum(bool(touching[a:b].any()) for a, b in zip(edges[::2], edges[1::2], strict=True))
        contact.setdefault(condition, []).append((float(dt[touching].sum()), touched))
    db.close()
    print(f"{'condition':14s} {'spot':7s} {'presses':>7s}  {'peak N median':>13s}  {'IQR':>11s}  "
          f"share > {f_crit:g} N")
    for condition in sorted(peaks):
        for spot in SPOTS:
            v = np.array(peaks[condition].get(spot, []))
            if v.size:
                q1, q2, q3 = np.percentile(v, [25, 50, 75])
                share = float(np.mean(v > f_crit))
                print(f"{condition:14s} {spot:7s} {v.size:7d}  {q2:13.2f}  {q1:5.2f}-{q3:5.2f}  {share:5.2f}")
    print(f"\n{'condition':14s} {'trials':>6s}  {'contact s/trial median':>22s}  {'tumour presses/trial':>20s}  "
          f"{'contact s/tumour press':>22s}")
    for condition in sorted(contact):
        c = np.array(contact[condition])
        per_press = c[:, 0].sum() / max(c[:, 1].sum(), 1)
        print(f"{condition:14s} {len(c):6d}  {np.median(c[:, 0]):22.2f}  {c[:, 1].mean():20.2f}  {per_press:22.3f}")


if __name__ == "__main__":
    from script_usage import argv_or_usage

    argv_or_usage(__doc__)
    if len(sys.argv) < 2:
        sys.exit("usage: python scripts/palpation_press_forces.py WORKSPACE/study.db [F_CRIT_N]")
    main(sys.argv[1], float(sys.argv[2]) if len(sys.argv) > 2 else 2.115)
