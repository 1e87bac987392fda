"""Every report of a simulated (or real) seed-002 study, true or false, with where it was and what was felt there.

Usage: ``python scripts/tissue_false_reports.py WORKSPACE [WORKSPACE ...]`` (a ``studyctl simulate
data_driven_palpation`` workspace; its study.db must still exist).

Per report (in the order made): participant, condition, its place in the trial's reports, when it was made
(seconds before the trial's end), hit or false (the protocol's one-to-one matching within its hit radius, as the
report's ``false_reports``), the nearest nodule and its distance, whether, within 20 mm of a nodule another
report of the same trial found, it is a second report of that nodule, and the distances to the phantom's nearest
two sides (its footprint; the phantom is thinnest, so stiffest, at its corners).
For haptic trials, from the stored samples: the stiffest press felt within 5 mm of the report (peak normal force,
N), against the stiffest press felt over each nodule (within 5 mm of its centre) in the same trial, as a ratio:
what the person had felt there against what the nodules gave. Manual trials store no samples (the finger touches
the phantom directly). Then a summary: false reports by condition, by place (corner: < 15 mm from two sides;
edge < 10 mm; near a found nodule < 20 mm, elsewhere) and by report order.

Why: seed 002's paper had 2 false reports in the whole study (one person, both at the phantom's edges, §V); the
shipped population makes 8 at seed 2024. This says which kind they are before anything is changed.
"""

from __future__ import annotations

import math
import sys
from collections import Counter

import numpy as np

from studyctl.analysis.trials import StoredStudy
from studyctl.models.palpation_metrics import match_reports
from studyctl.scenes.tissue import StiffnessTissueScene
from studyctl.store.reader import StudyReader

NEAR_MM = 5.0  # a press "at" a place: the indenter's contact within this of it
EDGE_MM = 10.0
NEAR_NODULE_MM = 20.0
CORNER_MM = 15.0  # within this of two sides: a corner, where the phantom is thinnest


def _felt(samples, x: float, y: float) -> float:
    """Peak normal force of the presses whose contact came within NEAR_MM of (x, y); NaN if none."""
    if samples.empty or "tissue_normal_n" not in samples:
        return math.nan
    cx, cy, f = (samples[c].to_numpy() for c in ("contact_x_mm", "contact_y_mm", "tissue_normal_n"))
    near = np.hypot(cx - x, cy - y) <= NEAR_MM
    near &= np.isfinite(f)
    return float(f[near].max()) if near.any() else math.nan


def rows(workspace: str) -> list[dict]:
    out = []
    with StudyReader.open(workspace=workspace) as reader:
        study = StoredStudy(reader)
        radius = float(study.protocol.trial.report.hit_radius)
        spec = study.protocol.scene.params
        for t in study.trials:
            reports = [r for r in t.reports if "x_mm" in r]
            nodules = list(t.truth["nodules"])
            owner, _ = match_reports(reports, nodules, radius)
            hit = {j for j in owner if j is not None}
            scene = StiffnessTissueScene.build(dict(spec), t.row.placement or {}, frozenset(), np.random.default_rng(0))
            x0, x1, y0, y1 = scene.mesh.footprint_mm
            samples = t.samples if t.condition != "manual" else None
            nod_felt = [] if samples is None else [_felt(samples, n["x_mm"], n["y_mm"]) for n in nodules]
            for k, r in enumerate(reports):
                d = [math.hypot(r["x_mm"] - n["x_mm"], r["y_mm"] - n["y_mm"]) for n in nodules]
                j = int(np.argmin(d))
                lx, ly, _ = scene.placement.to_local(r["x_mm"], r["y_mm"])
                edge, edge2 = sorted((lx - x0, x1 - lx, ly - y0, y1 - ly))[:2]
                felt = math.nan if samples is None else _felt(samples, lx, ly)
                top = max((v for v in nod_felt if math.isfinite(v)), default=math.nan)
                out.append({
                    "who": t.participant, "cond": t.condition, "order": k + 1, "n": len(reports),
                    "before_end_s": t.duration_s - float(r.get("t", t.duration_s)), "hit": k in hit,
                    "nodule": nodules[j]["name"], "dist": d[j], "again": k not in hit
                    and owner[j] is not None and d[j] < NEAR_NODULE_MM,
                    "edge": edge, "edge2": edge2, "felt": felt, "felt_ratio": felt / top if top > 0 else math.nan,
                    "x": r["x_mm"], "y": r["y_mm"],
                })
    return out


def place(r: dict) -> str:
    if r["edge2"] < CORNER_MM:
        return "corner"
    if r["edge"] < EDGE_MM:
        return "edge"
    if r["dist"] < NEAR_NODULE_MM:
        return "near a found nodule" if r["again"] else "near a nodule"
    return "between"


def main(workspaces: list[str]) -> None:
    for ws in workspaces:
        rs = rows(ws)
        print(f"== {ws}: {len(rs)} reports, {sum(not r['hit'] for r in rs)} false")
        print("who       cond    k/n  before_end_s  hit    nearest  dist_mm  again  edge_mm  2nd_edge  felt_N  "
              "felt/nodules  x,y")
        for r in rs:
            if r["hit"] and "--all" not in sys.argv:
                continue
            print(f"{r['who']:9} {r['cond']:7} {r['order']}/{r['n']}  {r['before_end_s']:11.3f}  {r['hit']!s:5}  "
                  f"{r['nodule']:7}  {r['dist']:7.1f}  {r['again']!s:5}  {r['edge']:7.1f}  {r['edge2']:8.1f}  "
                  f"{r['felt']:6.2f}  "
                  f"{r['felt_ratio']:12.2f}  {r['x']:.0f},{r['y']:.0f}")
        false = [r for r in rs if not r["hit"]]
        true = [r for r in rs if r["hit"]]
        print("false by condition:", dict(Counter(r["cond"] for r in false)))
        print("false by place:", dict(Counter(place(r) for r in false)))
        print("false by order:", dict(Counter(f"{r['order']}/{r['n']}" for r in false)))
        print(f"true: {len(true)}, edge_mm median {np.median([r['edge'] for r in true]):.1f}, dist median "
              f"{np.median([r['dist'] for r in true]):.1f}; haptic felt/nodules median "
              f"{np.nanmedian([r['felt_ratio'] for r in true if r['cond'] != 'manual']):.2f}")


if __name__ == "__main__":
    from script_usage import argv_or_usage

    main([a for a in argv_or_usage(__doc__) if not a.startswith("--")])
