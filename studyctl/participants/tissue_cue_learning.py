"""How reliable a tissue palpator has found each cue of a slid survey so far (:mod:`.tissue_decision`): a running
estimate pooled over the person's own slid trials, for ``slide_fusion: pooled``.

Why: the ideal observer adds two independent cues' z scores weighted by each cue's detectability d' (Green & Swets
1966; the detection form of Ernst & Banks 2002's inverse-variance weighting). A person does not know the d' of a
new cue; it learns it with exposure: cue weights shift towards the cues that proved reliable over trials (Ernst,
Banks & Bülthoff 2000, Nat Neurosci 3:69; Atkins, Fiser & Jacobs 2001, Vision Res 41:449). Estimated from one
trial's own records (``slide_fusion: reliability``), sqrt(mean z² − 1) of 139-288 windows has a sampling SD of
about 0.3 on an amplitude of 0.05-1.1 (measured, stop 29): the weights were mostly noise. Pooled over the trials
the person has slid, and shrunk towards equal reliability by a prior worth ``cue_prior_windows`` windows, the
estimate starts at equal weights (Stouffer) and moves to what the cues have shown as evidence accumulates.

Only what the person sensed enters: each record's z in its cue's own noise SDs, over the whole survey; nothing
about where nodules are. The tallies are the person's memory (:meth:`Participant.memory`), so a resumed session
goes on with what it had learnt.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

MIN_SIGNAL = 0.05  # CHOSEN: a twentieth of a noise SD: a cue that showed nothing still counts a little


def amplitude(excess: float) -> float:
    """What a cue has shown, in its own noise SDs, from the excess of its records (:func:`excess`): its square
    root, at least :data:`MIN_SIGNAL`."""
    return max(math.sqrt(max(excess, 0.0)), MIN_SIGNAL)


def sums(z: np.ndarray) -> tuple[float, float]:
    """The two sums a cue's excess is estimated from: of z² and of z·|z|."""
    return float(np.sum(z * z)), float(np.sum(z * np.abs(z)))


def excess(sum_z2: float, sum_zabs: float, n: float, statistic: str) -> float:
    """How much a cue's records stood out beyond noise, per record, in squared noise SDs.

    ``spread``: mean z² − 1, the method-of-moments excess of any spread beyond the noise's (stop 29's rule). It
    counts any spread the robust noise SD misses — a push that wobbles with the hand's dynamics looks reliable —
    and under-counts where the noise has lighter tails than a Gaussian. ``stiffer``: mean z·|z|, the excess of the
    stiffer side over the softer side's mirror image: zero for noise of any symmetric shape and scale, about
    (share of records over a nodule) × (its contrast in SDs)² otherwise, like ``spread`` for Gaussian noise. The
    person knows which side matters: the practice runs showed it nodules that feel harder than the tissue.
    Measured (Table 1, one person of v5's means, PHF+FF, seeds 100-109): the slowing's ``stiffer`` excess was
    0.18-0.72 in every trial while its ``spread`` was −0.11-1.06; the push's ``stiffer`` −0.43-0.39."""
    if n <= 0:
        return 0.0
    return sum_zabs / n if statistic == "stiffer" else sum_z2 / n - 1.0


class CueReliability:
    """Per cue, the sums of z² and z·|z| over the windows of the person's finished slid trials, and their count."""

    def __init__(self, prior_windows: float, statistic: str = "spread") -> None:
        self.prior_windows = float(prior_windows)
        self.statistic = statistic
        self.past: dict[str, tuple[float, float, int]] = {}  # cue -> (Σ z², Σ z|z|, windows) over finished trials
        self.now: dict[str, tuple[float, float, int]] = {}  # this trial's, replaced at every look at the evidence

    def signals(self, z_by_cue: Mapping[str, np.ndarray]) -> dict[str, float]:
        """Each cue's learnt amplitude given this trial's records so far (``z_by_cue``: the survey records' z).

        Pooled: the excess (:func:`excess`) of the past and this trial's windows together. Shrunk: the prior is the
        cues' common excess (the person believes its cues equally reliable until shown otherwise), worth
        ``prior_windows`` windows, so two cues with little exposure are weighted alike and with much exposure by
        what they showed."""
        self.now = {name: (*sums(z), int(z.size)) for name, z in z_by_cue.items()}
        pooled = {}
        for name, (a, b, n) in self.now.items():
            pa, pb, pn = self.past.get(name, (0.0, 0.0, 0))
            pooled[name] = excess(a + pa, b + pb, n + pn, self.statistic), n + pn
        total_n = sum(n for _, n in pooled.values())
        if total_n == 0:
            return {name: MIN_SIGNAL for name in pooled}
        common = sum(e * n for e, n in pooled.values()) / total_n
        k = self.prior_windows
        return {name: amplitude((e * n + k * common) / (n + k)) for name, (e, n) in pooled.items()}

    def commit(self) -> None:
        """The trial is over: what it showed joins the person's experience."""
        for name, (a, b, n) in self.now.items():
            pa, pb, pn = self.past.get(name, (0.0, 0.0, 0))
            self.past[name] = (pa + a, pb + b, pn + n)
        self.now = {}

    def to_json(self) -> dict[str, Any]:
        return {name: list(v) for name, v in sorted(self.past.items())}

    def load(self, data: Mapping[str, Any]) -> None:
        self.past = {str(name): (float(v[0]), float(v[1]), int(v[2])) for name, v in data.items()}
        self.now = {}
