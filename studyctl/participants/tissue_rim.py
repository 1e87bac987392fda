"""What a tissue palpator learns in practice about how firm the tissue feels where it looks thin
(``thickness_prior: learn``, off by default).

A slab lying on a table feels firmer where it is thin: the table is closer beneath the finger (a bonded thin layer's
indentation stiffness grows as its thickness falls; Hayes, Keer, Herrmann & Mockros 1972, J Biomech 5:541). The
person sees the slab and where it presses, so it sees how thick the tissue looks there. In the practice run it
presses plain tissue (away from the visible nodules) all over the block and can learn from those presses alone how
much firmer a plain press feels where the tissue looks thinner: the expectation it then brings to the test, so a
firm rim is what it expects there, not a nodule. The form (CHOSEN): a straight line, fitted by least squares, of
the log of a plain press's firmness (the push felt over what the tissue gives at that depth, as the decision reads
it before comparing a spot with its surroundings) on the visible thickness there; in the test each press's
firmness is divided by what that line expects at its visible thickness before the spot is compared with the tissue
around it. Only the person's own plain practice presses and what it saw enter; the test's nodules are never shown.
A contrast against the tissue around (25 mm) already holds most of the thickness trend (a line of it on thickness
was flat, +0.002 per mm, in the seed-12 practice of tests/tissue): what practice shows is the firmness itself.

``rim_slope: physics_sign`` (off by default) holds the learnt line to the physics' sign: thinner tissue over the
table never feels softer, so the line is fitted by least squares under the constraint slope <= 0. Where the
presses alone would give a slope >= 0 (about 16 stylus presses with noise SD 0.11 often do), the constrained
optimum is the flat line at the presses' mean log firmness: the person expects the same firmness at every
thickness, which corrects nothing. A slope < 0 is kept as learnt. The physics fixes only the sign, not a size, so
this adds no number (a shrinkage of the slope towards a prior would need a prior slope and spread nothing cites).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

MIN_PRESSES = 5  # a line is learnt only from at least this many plain presses that read the cue
MIN_SPREAD_MM = 2.0  # ... spanning at least this range of visible thickness (else there is no slope to see)


def learn_rim(cues: Sequence[tuple[np.ndarray, str]], plain: np.ndarray, height_mm: np.ndarray,
              physics_sign: bool = False) -> dict[str, dict[str, float]]:
    """Per cue, the line ``log firmness = a + b · height`` over the plain practice presses (``plain``), from each
    press's firmness (``cues``: values and cue name, as :meth:`_cue_values` gives them) and the visible thickness
    there (``height_mm``); with ``physics_sign`` the slope is held to b <= 0 (what the fit gave is kept as
    ``b_fitted_per_mm``)."""
    out: dict[str, dict[str, float]] = {}
    for values, name in cues:
        use = plain & np.isfinite(values) & (values > 0) & np.isfinite(height_mm)
        if use.sum() < MIN_PRESSES or np.ptp(height_mm[use]) < MIN_SPREAD_MM:
            continue
        logs = np.log(values[use])
        b, a = np.polyfit(height_mm[use], logs, 1)
        line = {"a": float(a), "b_per_mm": float(b), "n": int(use.sum())}
        if physics_sign and b >= 0.0:
            # the least-squares line with slope <= 0: flat at the mean (expects the same everywhere: no correction)
            line = {"a": float(np.mean(logs)), "b_per_mm": 0.0, "n": int(use.sum()), "b_fitted_per_mm": float(b)}
        out[name] = line
    return out


def expected_firmness(line: Mapping[str, float], height_mm: np.ndarray) -> np.ndarray:
    """How firm a plain press is expected to feel where the tissue looks ``height_mm`` thick."""
    return np.exp(float(line["a"]) + float(line["b_per_mm"]) * height_mm)
