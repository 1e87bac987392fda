"""What a tissue palpator learns in seed 003's practice run with visible nodules (``practice: weights|learn``).

Seed 003 gave each participant "a practice run with visible hard nodules" before each feedback condition's test. A
person who has pressed on and around nodules it can see, with that condition's feedback, knows per cue (the push
felt, the cursor's slowing) how much a press near a nodule stands out from the tissue around (its mean excess) and
how much plain presses vary (its spread). Two things follow, both the ideal observer's use of that knowledge:

* cue weights: independent Gaussian cues are best added with each contrast weighted by its mean difference over
  its variance (Green & Swets 1966, the linear discriminant; Ernst & Banks 2002 for the inverse-variance form).
  The fusion already divides by each cue's noise variance; the learnt part is the mean excess, as a share of the
  largest cue's, in place of the untaught ``force_trust`` / ``cursor_trust``. Cue weights are learnt with
  feedback about the truth (Atkins, Fiser & Jacobs 2001, Vision Res 41:449; Ernst, Banks & Bülthoff 2000);
* the criterion: a re-palpated spot's sequential test is nodule-with-the-learnt-excess against none (the likelihood
  ratio criterion of Green & Swets, with the alternative known from practice) instead of the survey's own shrunk
  contrast there, which the selection of the most suspicious spot inflates.

What the practice presses are (CHOSEN): ``practice_presses`` presses within half a press spacing of each visible
nodule's centre (where a survey press near a nodule lands; uniform over that disc), and twice as many on plain
tissue, on the survey's lattice at least a cluster radius beyond every nodule's edge. Only the person's own press
records enter, split by where it pressed relative to the marks it saw; the test trial's nodules are never shown.
A slid survey's cues are another reading (a slide, not a descent): the learnt weights apply to presses only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

MIN_PRESSES = 3  # a cue is learnt only when at least this many presses near the marks read it


def practice_points(lattice: Sequence[tuple[float, float]], marks: Sequence[Mapping[str, Any]], per_mark: int,
                    spacing_mm: float, clear_mm: float, on_tissue, rng: np.random.Generator
                    ) -> list[tuple[float, float]]:
    """Where the practice presses go, in the order pressed: ``per_mark`` points uniform within ``spacing_mm`` / 2 of
    each mark's centre (on the tissue), then ``2 × per_mark × marks`` lattice points at least ``clear_mm`` beyond
    every mark's edge, drawn without replacement; sorted along the survey lines (y, then x) to keep the moves short."""
    near: list[tuple[float, float]] = []
    for m in marks:
        cx, cy = float(m["x_mm"]), float(m["y_mm"])
        tries = 0
        placed = 0
        while placed < per_mark and tries < 50 * per_mark:
            tries += 1
            r = 0.5 * spacing_mm * math.sqrt(float(rng.random()))
            a = 2.0 * math.pi * float(rng.random())
            p = (cx + r * math.cos(a), cy + r * math.sin(a))
            if on_tissue(*p):
                near.append(p)
                placed += 1
    plain = [p for p in lattice if all(
        math.dist(p, (float(m["x_mm"]), float(m["y_mm"]))) >= 0.5 * float(m.get("diameter_mm", 0.0)) + clear_mm
        for m in marks)]
    count = min(2 * per_mark * len(marks), len(plain))
    chosen = [plain[i] for i in sorted(rng.choice(len(plain), size=count, replace=False))] if count else []
    return sorted(near + chosen, key=lambda p: (p[1], p[0]))


def near_marks(pts: np.ndarray, marks: Sequence[Mapping[str, Any]], reach_mm: float) -> np.ndarray:
    """Per press, the index of the mark whose centre it was within ``reach_mm`` of (the nearest), else -1: the
    person sees the marks and where it pressed."""
    out = np.full(len(pts), -1)
    best = np.full(len(pts), np.inf)
    for i, m in enumerate(marks):
        d = np.hypot(pts[:, 0] - float(m["x_mm"]), pts[:, 1] - float(m["y_mm"]))
        take = (d <= reach_mm) & (d < best)
        out[take], best[take] = i, d[take]
    return out


def learn(scaled: Sequence[tuple[np.ndarray, float, np.ndarray, str]], mark: np.ndarray) -> dict[str, dict[str, float]]:
    """Per cue, from one practice's presses (``scaled``: contrast against the plain presses' local baseline, its
    robust noise SD over the plain presses, which contrasts are finite, the cue's name; ``mark``: the mark each
    press was near, -1 for plain): the mean excess of the presses near the marks, the mean excess of the faintest
    mark (its presses' mean; the nodule hardest to tell), the plain presses' spread and how many presses near the
    marks read it."""
    out: dict[str, dict[str, float]] = {}
    for contrast, sigma, ok, name in scaled:
        on = (mark >= 0) & ok
        if on.sum() < MIN_PRESSES:
            continue
        per_mark = [float(np.mean(contrast[on & (mark == i)])) for i in np.unique(mark[on])]
        out[name] = {"excess": float(np.mean(contrast[on])), "faintest": min(per_mark), "sd": float(sigma),
                     "n": int(on.sum())}
    return out


def trust(learnt: Mapping[str, Mapping[str, float]]) -> dict[str, float] | None:
    """Each cue's weight factor: its learnt mean excess over the largest one's (a cue that did not stand out on the
    nodules gets 0); None when no cue stood out (the untaught trust stays)."""
    gains = {name: max(float(c["excess"]), 0.0) for name, c in learnt.items()}
    top = max(gains.values(), default=0.0)
    if top <= 0:
        return None
    return {name: g / top for name, g in gains.items()}


def nodule_contrast(learnt: Mapping[str, Mapping[str, float]]) -> float | None:
    """A press near the faintest nodule's fused contrast as practice showed it (the alternative a re-palpated spot
    is tested for: a person looking for every nodule it was shown tests a spot against the one hardest to feel;
    CHOSEN): the cues' excesses on that mark averaged with the fusion's weights (learnt trust over the noise
    variance); None without a cue that stood out, or when the faintest mark showed no excess at all."""
    weights = trust(learnt)
    if weights is None:
        return None
    num = den = 0.0
    for name, c in learnt.items():
        w = weights[name] / max(float(c["sd"]), 1e-9) ** 2
        num += w * float(c.get("faintest", c["excess"]))
        den += w
    return num / den if den > 0 and num > 0 else None
