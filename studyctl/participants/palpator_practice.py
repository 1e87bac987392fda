"""What a palpator learns on the example phantom: which felt and seen cues tell a tumour from sponge, and how much.

Seed 000 gave every participant up to 5 minutes before each trial on an example phantom "on which the locations of
3 different types of tumors were marked", to get used to the feedback being tested (Methods II.D.3). A person who
has pressed the marked sites and plain sponge with this feedback knows, cue by cue (each note the palpator takes:
balloon and vibration at checkpoints of the press and at their peaks, the camera's yield), how far a tumour moves it
and how much it varies from press to press, and judges a cell by all of them together.

The combination is the ideal observer of independent Gaussian cues: the weight of a cue is its mean difference over
its variance (the linear discriminant with a diagonal covariance; Ernst & Banks 2002 for cue combination by
reliability). The variances are what the person felt over the practice presses — the senses' Weber noise and the
press-to-press variation of the hand and the feedback together — so a cue that varies a lot on plain sponge gets
little weight. Because the notes of one press are correlated (checkpoints of one channel), the spread of the
combined evidence is taken from the plain practice presses themselves, not from the sum of the cue variances.
``cue_learning: shrinkage`` (off by default) solves one discriminant over all noted cues instead
(:func:`shrinkage_weights`); measured on the real presses it is no better: with ~12 presses per kind the weights are
noisy whichever form they take (README, "What practice learns"). ``cue_learning: by_mark`` (off by default) takes
the tumour presses' variance within each marked site: the marks show which tumour is which (Methods II.D.3), so the
spread between a hard and a soft mark is not press-to-press noise; measured, it barely moves what is learnt (README).
``practice_rule: until_learnt`` (off by default) spends the paper's time as a person would: after the fixed presses it
keeps pressing a mark that does not yet feel different from sponge (no cue at t ≥ 2) until it does or its share of
the 5 min is used, a plain cell after each press; 4 presses a mark (~20 s) taught little about soft tumours (README).
With ``learnt_bar: combined`` (off by default) a mark is learnt only when the combined evidence the trial uses tells it
from sponge at t ≥ 2, not when any one of ~11 cues does (README).

:class:`Familiarisation` is the palpator's side of it (a mixin of
:class:`~studyctl.participants.palpator.VirtualPalpator`): which sites the practice presses, and the learning once
they are pressed.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.models.grid_cells import within_one_cell
from studyctl.participants.palpator_perception import VISUAL
from studyctl.plugins.interfaces import Action, Request

Key = tuple[str, str]

MIN_SHARE = 0.8  # a cue is learnt only when it was noted on this share of both kinds of practice press
MIN_PRESSES = 3  # and on at least this many of each
MIN_T = 2.0  # a cue counts only when its practice difference stood out from its press-to-press spread (t ≥ 2):
# with ~12 presses of each kind the mean differences of many cues are mostly noise, and a person does not rely on
# a cue they never noticed to differ (the weights of unnoticed cues are 0: shrinkage by selection)


@dataclass(frozen=True)
class CueWeights:
    """Learnt weights, plain-sponge centres and the spread of the combined evidence on plain sponge."""

    keys: tuple[Key, ...]
    weights: tuple[float, ...]
    centres: tuple[float, ...]
    spread: float  # SD of one plain press's combined evidence
    separation: float  # mean tumour-minus-plain combined evidence of one practice press, in spreads
    prior: float = 0.0  # share of the example phantom's cells that were marked tumours (0: not known)

    def combine(self, logs: Mapping[Key, float]) -> float | None:
        """One press's combined evidence (a cue not noted in this press counts as plain: adds 0); None when no
        learnt cue was noted at all."""
        total = 0.0
        seen = False
        for key, w, c in zip(self.keys, self.weights, self.centres, strict=True):
            v = logs.get(key)
            if v is not None:
                total += w * (v - c)
                seen = True
        return total if seen else None

    def to_json(self) -> dict[str, Any]:
        return {"keys": [list(k) for k in self.keys], "weights": list(self.weights), "centres": list(self.centres),
                "spread": self.spread, "separation": self.separation, "prior": self.prior}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> CueWeights:
        return cls(tuple((str(a), str(b)) for a, b in data["keys"]), tuple(float(v) for v in data["weights"]),
                   tuple(float(v) for v in data["centres"]), float(data["spread"]), float(data["separation"]),
                   float(data.get("prior", 0.0)))


def _noted(tumour: Sequence[Mapping[Key, float]], plain: Sequence[Mapping[Key, float]]) -> list[Key]:
    """The cues noted often enough on both kinds of practice press to be learnt at all."""
    out = []
    for key in sorted({k for press in (*tumour, *plain) for k in press}):
        t = sum(key in p for p in tumour)
        s = sum(key in p for p in plain)
        if min(t, s) >= MIN_PRESSES and t >= MIN_SHARE * len(tumour) and s >= MIN_SHARE * len(plain):
            out.append(key)
    return out


def _within_ss(values: Sequence[float], groups: Sequence[Hashable]) -> tuple[float, int]:
    """Sum of squares of ``values`` about their own group's mean, and the number of groups."""
    by: dict[Hashable, list[float]] = {}
    for v, g in zip(values, groups, strict=True):
        by.setdefault(g, []).append(v)
    return sum(sum((v - sum(vs) / len(vs)) ** 2 for v in vs) for vs in by.values()), len(by)


def _diagonal_weights(tumour: Sequence[Mapping[Key, float]], plain: Sequence[Mapping[Key, float]],
                      floor: Mapping[str, float], marks: Sequence[Hashable] | None = None,
                      ) -> tuple[list[Key], list[float], list[float]]:
    """Each cue on its own: weight = mean difference / variance, kept only when it stood out (t ≥ MIN_T).

    ``marks`` (one per tumour press: which marked site it was on) takes the tumour presses' variance about each
    mark's own mean (Fisher's pooled within-class variance, Duda, Hart & Stork 2001, sec. 3.8): the practice shows
    which mark is which tumour, so how far a hard mark moves a cue beyond a soft one is not press-to-press noise.
    None: about the mean of all tumour presses (the shipped form, where the spread between the marks counts as noise).
    """
    keys: list[Key] = []
    weights: list[float] = []
    centres: list[float] = []
    for key in _noted(tumour, plain):
        t = [p[key] for p in tumour if key in p]
        s = [p[key] for p in plain if key in p]
        mt, ms = sum(t) / len(t), sum(s) / len(s)
        if marks is None:
            ss_t, groups = sum((v - mt) ** 2 for v in t), 1
        else:
            ss_t, groups = _within_ss(t, [g for p, g in zip(tumour, marks, strict=True) if key in p])
        pooled = (ss_t + sum((v - ms) ** 2 for v in s)) / max(len(t) + len(s) - 1 - groups, 1)
        var = max(pooled, floor.get(key[0], 0.0), 1e-12)
        if abs(mt - ms) < MIN_T * math.sqrt(var * (1 / len(t) + 1 / len(s))):
            continue
        keys.append(key)
        weights.append((mt - ms) / var)
        centres.append(ms)
    return keys, weights, centres


def shrinkage_weights(tumour: Sequence[Mapping[Key, float]], plain: Sequence[Mapping[Key, float]],
                      floor: Mapping[str, float]) -> tuple[list[Key], list[float], list[float]]:
    """All noted cues together: the linear discriminant with the notes' correlations shrunk towards none.

    The pooled press-to-press covariance of ~24 presses over ~11 notes is too noisy to invert as it is (the checkpoint
    notes of one channel correlate, and their contrast is learnt from noise), so its correlations are shrunk towards
    0 by the data-chosen intensity of Schäfer & Strimmer (2005, Stat Appl Genet Mol Biol 4:32, target "D": unequal
    variances, no correlation) — between the full discriminant (intensity 0) and the independent-cue rule (1).
    Variances keep the senses' Weber floor. CHOSEN: a cue whose weight comes out against the direction it moved on
    the marks is not used (the discriminant is solved again without it): people weight correlated cues below the
    optimum but do not read a cue backwards. A missing note counts as its kind's mean (it adds no spread).
    """
    keys = _noted(tumour, plain)
    if not keys:
        return [], [], []

    def matrix(presses: Sequence[Mapping[Key, float]]) -> tuple[np.ndarray, np.ndarray]:
        x = np.array([[p.get(k, np.nan) for k in keys] for p in presses], dtype=float)
        mean = np.nanmean(x, axis=0)
        return np.where(np.isnan(x), mean, x), mean

    xt, mt = matrix(tumour)
    xs, ms = matrix(plain)
    centred = np.vstack([xt - mt, xs - ms])
    n = centred.shape[0]
    cov = centred.T @ centred / max(n - 2, 1)
    var = np.maximum(np.diag(cov), [max(floor.get(k[0], 0.0), 1e-12) for k in keys])
    sd = np.sqrt(var)
    z = centred / sd
    corr = cov / np.outer(sd, sd)
    np.fill_diagonal(corr, 1.0)
    off = ~np.eye(len(keys), dtype=bool)
    products = z[:, :, None] * z[:, None, :]  # press by press, the terms whose mean is the correlation
    var_r = n / (n - 1) ** 3 * ((products - products.mean(axis=0)) ** 2).sum(axis=0) if n > 1 else np.zeros_like(corr)
    denom = float((corr[off] ** 2).sum())
    intensity = min(max(float(var_r[off].sum()) / denom, 0.0), 1.0) if denom > 0 else 1.0
    shrunk = np.outer(sd, sd) * ((1 - intensity) * corr + intensity * np.eye(len(keys)))
    diff = mt - ms
    use = np.ones(len(keys), dtype=bool)
    weights = np.zeros(len(keys))
    while use.any():
        weights[:] = 0.0
        weights[use] = np.linalg.solve(shrunk[np.ix_(use, use)], diff[use])
        backwards = use & (weights * diff <= 0)
        if not backwards.any():
            break
        use &= ~backwards
    kept = [i for i in range(len(keys)) if use[i]]
    return [keys[i] for i in kept], [float(weights[i]) for i in kept], [float(ms[i]) for i in kept]


def learn_cue_weights(tumour: Sequence[Mapping[Key, float]], plain: Sequence[Mapping[Key, float]],
                      floor: Mapping[str, float], prior: float = 0.0, rule: str = "diagonal",
                      marks: Sequence[Hashable] | None = None) -> CueWeights | None:
    """Weights from the log-notes of practice presses on marked tumours and on plain sponge (one mapping per press).

    ``floor``: per channel, the variance no cue of it can go below (the sense's own Weber noise squared); ``prior``:
    the share of the phantom's cells that were marked tumours (kept for the report criterion); ``rule``: diagonal
    (each cue on its own, kept when t ≥ 2), by_mark (the same, its variance within each marked site: ``marks`` names
    the site of each tumour press) or shrinkage (:func:`shrinkage_weights`). None when no cue was noted often enough
    or the combined evidence does not vary on plain sponge.
    """
    if rule == "shrinkage":
        keys, weights, centres = shrinkage_weights(tumour, plain, floor)
    else:
        keys, weights, centres = _diagonal_weights(tumour, plain, floor, marks if rule == "by_mark" else None)
    if not keys:
        return None
    draft = CueWeights(tuple(keys), tuple(weights), tuple(centres), 1.0, 0.0)
    s_plain = [v for v in (draft.combine(p) for p in plain) if v is not None]
    s_tumour = [v for v in (draft.combine(p) for p in tumour) if v is not None]
    if len(s_plain) < MIN_PRESSES or not s_tumour:
        return None
    mean_p = sum(s_plain) / len(s_plain)
    spread = math.sqrt(sum((v - mean_p) ** 2 for v in s_plain) / (len(s_plain) - 1))
    if not spread > 0:
        return None
    separation = (sum(s_tumour) / len(s_tumour) - mean_p) / spread
    return CueWeights(draft.keys, draft.weights, draft.centres, spread, separation, prior)


def _combined_separates(logs: Sequence[tuple[Hashable, Mapping[Key, float]]], marked: Any, cell: Hashable,
                        floor: Mapping[str, float], rule: str) -> bool:
    """``learnt_bar: combined``: the evidence the trial will judge cells by — cue weights learnt (by ``rule``), here
    from the other marks' and the plain presses so far, held out so that ``cell``'s own noise cannot pass it — is
    higher on ``cell``'s presses than on the plain presses by t ≥ MIN_T, in the plain presses' spread. Stricter than
    one cue at t ≥ 2: the weights are set mostly by the marks that differ most (hard, medium), so a soft mark counts
    as learnt only when what the person will go by tells it from sponge."""
    held_out = [(c, p) for c, p in logs if c in marked and c != cell]
    plain = [p for c, p in logs if c not in marked]
    cues = learn_cue_weights([p for _, p in held_out], plain, floor, 0.0, rule, [c for c, _ in held_out])
    if cues is None:
        return False
    here = [v for v in (cues.combine(p) for c, p in logs if c == cell) if v is not None]
    there = [v for v in (cues.combine(p) for p in plain) if v is not None]
    if not here or len(there) < MIN_PRESSES:
        return False
    diff = sum(here) / len(here) - sum(there) / len(there)
    return diff >= MIN_T * cues.spread * math.sqrt(1 / len(here) + 1 / len(there))


class Familiarisation:
    """Mixin of :class:`~studyctl.participants.palpator.VirtualPalpator`: the practice run on the example phantom
    (``familiarise``): which sites it presses, and what it learns from them when the presses are done."""

    def _queue_practice(self, marks: Any) -> None:
        """Press each marked site and as many plain cells (two cells or more from every mark), practice_presses
        times each site; the marks are drawn on the example phantom (positions, or their grid cells)."""
        n = self.params["practice_presses"]
        sites = []
        for m in marks:
            xy = (m.get("x_mm"), m.get("y_mm")) if isinstance(m, Mapping) else (None, None)
            if all(isinstance(v, int | float) for v in xy):
                x, y = float(m["x_mm"]), float(m["y_mm"])
                cell = (int(math.floor((x - self.origin[0]) / self.cell_mm)) + 1,
                        int(math.floor((y - self.origin[1]) / self.cell_mm)) + 1)
                sites.append((cell, (x, y)))
        if not sites:
            raise ModelParameterError("virtual_palpator: the practice phantom shows no marks (x_mm, y_mm of each "
                                      "marked site in the trial's public 'marks'); familiarise needs them")
        self._marked = {cell for cell, _ in sites}
        plain = [(c, r) for r in range(1, self.rows + 1) for c in range(1, self.columns + 1)
                 if not any(within_one_cell((c, r), m) for m in self._marked)]
        for cell, at in sites:
            for _ in range(n):
                self._queue_probe(cell, at)
        count = min(n * len(sites), len(plain))
        for i in sorted(self._rng.choice(len(plain), size=count, replace=False)):
            self._queue_probe(plain[i])
        self._plain_cells = plain
        self._to_learn = list(sites) if self.params["practice_rule"] == "until_learnt" else []
        self._share_end: float | None = None

    def _practise_more(self, t: float) -> bool:
        """``practice_rule: until_learnt``, when the queued presses are done at practice time ``t``: press the mark
        being learnt once more, and a plain cell after it, unless that mark is learnt (:meth:`_mark_learnt`) or its
        share of the time left is used; then go on to the next mark. True when presses were queued.

        The budget is the practice's own time limit (the protocol's 5 min, Methods II.D.3), less the margin the
        palpator keeps before any time limit; each mark gets an equal share of what is left when its turn comes
        (CHOSEN: time a mark learnt quickly goes to the marks after it). A pair is only started when it fits in the
        share, its length taken as the practice's mean time per press so far."""
        while self._to_learn:
            cell, at = self._to_learn[0]
            if self._share_end is None:
                self._share_end = t + max(self._report_by_s - t, 0.0) / len(self._to_learn)
            pair_s = 2.0 * t / max(len(self._press_logs), 1)
            if t + pair_s <= self._share_end and not self._mark_learnt(cell):
                self._queue_probe(cell, at)
                self._queue_probe(self._plain_cells[int(self._rng.integers(len(self._plain_cells)))])
                return True
            self._to_learn.pop(0)
            self._share_end = None
        return False

    def _mark_learnt(self, cell: tuple[int, int]) -> bool:
        """What this mark feels like is learnt: on some cue its presses so far differ from the plain presses so far
        by t ≥ MIN_T (the learner's own test, its variance within the mark: the person keeps pressing a mark until
        it clearly feels different from sponge, the same bar a cue must pass to be used at all)."""
        if self.params["learnt_bar"] == "combined":
            return _combined_separates(self._press_logs, self._marked, cell, self._floor(),
                                       self.params["cue_learning"])
        tumour = [logs for c, logs in self._press_logs if c == cell]
        plain = [logs for c, logs in self._press_logs if c not in self._marked]
        return bool(_diagonal_weights(tumour, plain, self._floor())[0])

    def _floor(self) -> dict[str, float]:
        """Per channel, the variance no cue can go below: the sense's own Weber noise squared."""
        floor = {ch: sense.sigma**2 for ch, sense in self.senses.items()}
        floor[VISUAL[0]] = self.senses["view"].sigma ** 2
        return floor

    def _learn_and_finish(self) -> Action:
        """End of practice: learn the cue weights from the presses on the marks and on plain sponge, then finish."""
        tumour = [logs for cell, logs in self._press_logs if cell in self._marked]
        marks = [cell for cell, _ in self._press_logs if cell in self._marked]
        plain = [logs for cell, logs in self._press_logs if cell not in self._marked]
        floor = self._floor()
        # what the example phantom showed: this many marked tumours among its cells (the prior of the report rule)
        prior = len(self._marked) / max(self.columns * self.rows, 1)
        self.cues = learn_cue_weights(tumour, plain, floor, prior, self.params["cue_learning"], marks)
        self._finished = True
        return Action(inputs={"x_mm": self._pose[0], "y_mm": self._pose[1], "depth_mm": -5.0},
                      requests=(Request("finish"),))
