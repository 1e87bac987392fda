"""How the seed-000 virtual palpator decides (:mod:`studyctl.participants.palpator`): after the sweep, the reference
of normal tissue per note (the median over the cells), each cell's evidence against it in noise SDs (or, after
practice, its combined evidence by the learnt cue weights), the cells re-probed, and the cells reported (the
strongest of neighbours, at most ``max_reports``; a guess when nothing stood out).

:class:`CellDecision` is a mixin of :class:`~studyctl.participants.palpator.VirtualPalpator`.
"""

from __future__ import annotations

import math

import numpy as np

from studyctl.models.grid_cells import within_one_cell
from studyctl.participants.exact_mean import numpy_mean
from studyctl.participants.palpator_perception import STOP, VISUAL, _CellEvidence
from studyctl.plugins.interfaces import Action, Request


def _scipy_stats():  # noqa: ANN202 - the scipy.stats module
    from scipy import stats  # noqa: PLC0415 - about a second to import: see VirtualPalpator.__init__

    return stats


class CellDecision:
    """Mixin of :class:`~studyctl.participants.palpator.VirtualPalpator`: reference, scores, re-probes, reports."""

    def _reference(self) -> dict[tuple[str, str], float | None]:
        """Median log-percept over the swept cells per (channel, checkpoint); None when normal tissue is not felt.

        Also sets ``_felt_rate``: the share of cells felt at each note on the first press (add-one smoothed),
        the base rate for the "felt here but not on normal tissue" test, and ``_spread``: the robust SD of the
        first-press log-percepts over the cells (how much pressing normal tissue varies, noise of the senses,
        of the hand's depth and of the feedback itself together), used with ``judge_spread``.
        """
        ref: dict[tuple[str, str], float | None] = {}
        self._felt_rate = {}
        self._spread = {}
        n = len(self.evidence)
        for key in self._keys:
            first = [ev.logs[key][0] if ev.logs.get(key) else -math.inf for ev in self.evidence.values()]
            med = float(np.median(first)) if first else -math.inf
            ref[key] = med if math.isfinite(med) and key != STOP else None
            felt_logs = np.array([v for v in first if math.isfinite(v)])
            if ref[key] is not None and felt_logs.size >= 5:
                # how much normal tissue itself varies from press to press (robust SD: 1.4826 x MAD)
                self._spread[key] = 1.4826 * float(np.median(np.abs(felt_logs - ref[key])))
            felt = sum(1 for ev in self.evidence.values() if ev.felt.get(key, 0)) if key == STOP else sum(
                1 for v in first if math.isfinite(v))
            self._felt_rate[key] = (felt + 1) / (n + 2)
        firsts = [ev.combined[0] for ev in self.evidence.values() if ev.combined]
        # what plain sponge gives by the learnt cues in this trial: the median over the surveyed cells
        self._ref_combined = float(np.median(firsts)) if firsts else None
        return ref

    def _score(self, ev: _CellEvidence, ref: dict[tuple[str, str], float | None]) -> float:
        """Evidence that a cell differs from normal tissue, in noise SDs of its mean (inf: felt only here).

        After practice (``familiarise``): the combined evidence of the learnt cues against this trial's plain
        level, in SDs of its mean (the practice's plain-sponge spread over the cell's presses)."""
        if self.cues is not None:
            if not ev.combined or self._ref_combined is None:
                return -math.inf
            return (numpy_mean(ev.combined) - self._ref_combined) / (self.cues.spread / math.sqrt(len(ev.combined)))
        stats = _scipy_stats()
        best = -math.inf
        for key in self._keys:
            logs = ev.logs.get(key)
            if ref[key] is None:
                # normal tissue mostly not felt here: how surprising is being felt in k of n presses?
                k = ev.felt.get(key, 0)
                if k:
                    p_tail = float(stats.binom.sf(k - 1, ev.presses, self._felt_rate[key]))
                    best = max(best, float(stats.norm.isf(max(p_tail, 1e-300))))
                continue
            if not logs:
                continue
            sigma = self.senses[key[0]].sigma
            if self.params["judge_spread"]:
                sigma = max(sigma, self._spread.get(key, 0.0))
            z = (numpy_mean(logs) - ref[key]) / (sigma / math.sqrt(len(logs)))
            if key == VISUAL:
                z *= self.params["visual_trust"]
            best = max(best, z)
        return best

    def _queue_confirmations(self, first: bool = True) -> None:
        """Re-probe the cells that stood out; after the first round only those still undecided (evidence between
        screen_z and report_z). With ``sure_odds`` the first round also skips the cells already past that bound."""
        if first:
            self._ref = self._reference()
        ref = self._ref
        p = self.params
        sure = p["sure_odds"]

        def bound(ev: _CellEvidence) -> float:
            # first round: every screened cell, or with sure_odds those not yet past its bound; later: undecided
            if first:
                return self._level(ev, sure) if sure > 0 else math.inf
            return self._level(ev)

        candidates = [cell for cell, ev in self.evidence.items()
                      if self._screen(ev) < self._score(ev, ref) <= bound(ev)]
        for cell in candidates:
            for _ in range(self.params["confirm_presses"]):
                self._queue_probe(cell)

    def _screen(self, ev: _CellEvidence) -> float:
        """The evidence above which a cell is probed again. ``screen_z`` noise SDs; with ``dismiss_odds`` (after
        practice, odds rule) the lower bound of Wald's sequential test instead: a cell is dropped only once a tumour
        there is that unlikely (odds below ``dismiss_odds``), so a feedback whose practice showed a weak separation
        leaves more cells undecided, to be probed again, and one that told tumours apart clearly leaves fewer."""
        odds = self.params["dismiss_odds"]
        if odds > 0 and self._odds_rule():
            return self._level(ev, odds)
        return self.params["screen_z"]

    def _odds_rule(self) -> bool:
        """Whether the likelihood-ratio criterion applies: ``report_rule: odds`` and a practice that showed a
        separation and a tumour share (see :meth:`_level`)."""
        cues = self.cues
        return self.params["report_rule"] == "odds" and cues is not None and cues.separation > 0 and 0 < cues.prior < 1

    def _decide_and_finish(self) -> Action:
        if self._finished:
            return Action(requests=(Request("finish"),))
        ref = self._ref or self._reference()
        scored = sorted(
            ((self._score(ev, ref), cell) for cell, ev in self.evidence.items()),
            key=lambda sc: (-sc[0], sc[1]),
        )
        chosen: list[tuple[int, int]] = []
        for score, cell in scored:
            if score <= self._level(self.evidence[cell]):
                continue  # (with one level for every cell, every later cell is below it too)
            if not any(within_one_cell(cell, c) for c in chosen):
                chosen.append(cell)
                if len(chosen) == self.params["max_reports"]:
                    break
        if not chosen and self.params["guesses"]:
            chosen = self._guess(scored)
        self.reports = chosen
        self._finished = True
        requests = tuple(Request("report", {"column": c, "row": r}) for c, r in chosen) + (Request("finish"),)
        return Action(inputs={"x_mm": self._pose[0], "y_mm": self._pose[1], "depth_mm": -5.0}, requests=requests)

    def _level(self, ev: _CellEvidence, odds: float = 1.0) -> float:
        """The evidence a cell needs to be reported, in the units of its score (with ``odds`` > 1: the evidence
        that makes a tumour that many times likelier than not, the bound where ``sure_odds`` stops re-probing; only
        the odds rule has one, else there is none: inf).

        ``report_rule: z``: ``report_z``, the same for every cell. ``report_rule: odds``, after practice: report a
        cell when a tumour is more likely there than not, given what the practice showed: the likelihood-ratio
        criterion of signal detection (Green & Swets 1966: report when the likelihood ratio exceeds P(no tumour) /
        P(tumour), with equal costs of a miss and a false report). The practice gave the person the separation s of
        one press on a marked tumour from plain sponge (in spreads) and the share of cells that were tumours (the
        prior p: 3 marked of 49). For n presses the cell's score z (its mean in SDs of the mean) has likelihood ratio
        exp(d z - d²/2) with d = s √n, so the criterion is z > d/2 + ln((1 - p)/p)/d: about 2.4 SDs for a person
        whose practice presses told tumours by 2-3 spreads. The fixed report_z (fitted for the unpractised rule, the
        strongest of ~13 notes, a maximum that runs high on plain sponge) asks 4 of the one combined score, and left
        most practised trials with nothing reported, so they ended in random guesses whatever the feedback
        (measured: scripts/palpation_practice_decision.py)."""
        cues = self.cues
        if self._odds_rule():
            d = cues.separation * math.sqrt(max(len(ev.combined), 1))
            return d / 2 + math.log(odds * (1 - cues.prior) / cues.prior) / d
        return self.params["report_z"] if odds == 1.0 else math.inf

    def _guess(self, scored: list[tuple[float, tuple[int, int]]]) -> list[tuple[int, int]]:
        """The cells reported when nothing stood out. ``random``: distinct cells drawn at random. ``best``: the
        cells whose evidence was strongest, not neighbouring each other (the max rule of a forced choice), and
        random cells only where no evidence at all was gathered (a person who noted nothing)."""
        cells = [(c, r) for r in range(1, self.rows + 1) for c in range(1, self.columns + 1)]
        n = min(self.params["guesses"], len(cells))
        chosen: list[tuple[int, int]] = []
        if self.params["guess"] == "best":
            for score, cell in scored:
                if len(chosen) == n or not math.isfinite(score):
                    break
                if not any(within_one_cell(cell, c) for c in chosen):
                    chosen.append(cell)
            if len(chosen) == n:
                return chosen
            cells = [c for c in cells if c not in chosen]
        idx = self._rng.choice(len(cells), size=n - len(chosen), replace=False)
        return chosen + [cells[i] for i in sorted(idx)]
