"""Expand a protocol into one participant's ordered plan, deterministically.

The plan of a participant depends only on (protocol, seed, stratum, slot) and
:data:`SCHEDULE_ALGORITHM_VERSION`: expanding again gives the identical plan, so the stored plan can
always be re-derived and compared. ``slot`` is the 0-based allocation slot, counted within the
participant's stratum (or across the study when ``counterbalance.within_strata`` is false).

Random draws come from one ``numpy.random.Generator`` per participant (PCG64 seeded by
``SeedSequence(seed, spawn_key=(stratum key, slot))``), consumed in a fixed order: the random
condition order (scheme ``random`` only), then placements, then orientations. Only ``random()``
doubles are drawn and turned into choices here, so the plans do not depend on numpy's
integer-sampling algorithms.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterable, Sequence
from operator import ne
from typing import TYPE_CHECKING, Any

import numpy as np

from studyctl.errors import UsageError
from studyctl.protocol import counterbalance as cbal
from studyctl.protocol.schema import Protocol
from studyctl.protocol.stored_plan import PLAN_COLUMNS, PlanEntry, Schedule, format_placement  # noqa: F401

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built: loading or checking a
    import pandas as pd  # protocol stays a small process (issue 19: hostile files within 200 MB)

SCHEDULE_ALGORITHM_VERSION = 1

_PURPOSE_PARTICIPANT = 0
_PURPOSE_ALLOCATION = 1

def stratum_key(stratum: str) -> int:
    """A stable 32-bit key of a stratum id for seeding (CRC-32 of its UTF-8 bytes)."""
    return zlib.crc32(stratum.encode("utf-8"))


def participant_rng(seed: int, stratum_key_value: int, slot: int) -> np.random.Generator:
    """The participant's generator: PCG64 from ``SeedSequence(seed, spawn_key=(0, stratum, slot))``."""
    return np.random.Generator(
        np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(_PURPOSE_PARTICIPANT, stratum_key_value, slot)))
    )


class Planner:
    """Everything about a protocol that does not depend on the participant, computed once.

    ``Planner(protocol).expand(seed=..., slot=..., stratum=...)`` is what :func:`expand_schedule`
    does; keep a planner to expand many participants quickly.
    """

    def __init__(self, protocol: Protocol) -> None:
        self.protocol = protocol
        self._protocol_id, self._protocol_sha256 = protocol.study.id, protocol.sha256
        cb = protocol.counterbalance
        self.fixed = tuple(cb.fixed_first)
        ordered = cb.conditions if cb.conditions is not None else [
            c for c in protocol.condition_ids if c not in self.fixed
        ]
        self.ordered = tuple(ordered)
        self.scheme = cb.scheme
        k = len(self.ordered)
        if cb.scheme == "williams":
            rows = cbal.williams(k)
        elif cb.scheme == "cyclic_latin":
            rows = cbal.cyclic_latin(k)
        elif cb.scheme == "all_permutations":
            rows = cbal.all_permutations(k)
        elif cb.scheme == "explicit":
            index = {c: i for i, c in enumerate(self.ordered)}
            rows = np.asarray([[index[c] for c in order] for order in (cb.orders or [])], dtype=np.int64)
        else:
            rows = None
        self.sequences: tuple[tuple[str, ...], ...] | None = (
            None if rows is None else tuple(self.fixed + tuple(self.ordered[i] for i in row) for row in rows.tolist())
        )
        self.allocation = cb.allocation
        self.block_size = cb.block_size or 1
        self.within_strata = cb.within_strata
        design = protocol.design
        self.repetitions, self.blocks, self.block_order = design.repetitions, design.blocks, design.block_order
        trial = protocol.trial
        self.time_limit = trial.time_limit_s
        fam = trial.familiarisation
        self.fam_s = None if fam is None else fam.max_s
        self.fam_each = fam is not None and fam.when == "before_each_condition"
        self.break_s = trial.break_s
        self.break_each_trial = trial.break_between == "trials"
        placement = protocol.scene.placement
        self.items = tuple(placement.items) if placement else ()
        self.sites = placement.sites if placement else 0
        self.place_rule = placement.differ_from_previous if placement else "none"
        orientation = protocol.scene.orientation
        self.orient_choices = tuple(orientation.choices_deg) if orientation else ()
        self.orient_per = orientation.per if orientation else "condition"
        self.orient_differ = bool(orientation and orientation.differ_from_previous)
        self.strata = protocol.stratum_ids
        self._stratum_keys = {s: stratum_key(s) for s in self.strata}
        admins = protocol.questionnaires
        self.q_start = tuple(a.instrument for a in admins if a.when == "start")
        self.n_trials = len(self.fixed + self.ordered) * self.repetitions * self.blocks
        self._place_batch = max(8, 2 * self.n_trials)
        self.needs_rng = self.sequences is None or bool(self.items) or bool(self.orient_choices)
        self._skeletons: dict[tuple[str, ...], tuple[tuple[Any, ...], ...]] = {}
        self._plain_entries: dict[tuple[str, ...], tuple[PlanEntry, ...]] = {}
        self._admins = [(a.instrument, a.when, None if a.conditions is None else frozenset(a.conditions))
                        for a in admins if a.when != "start"]

    # -- allocation -------------------------------------------------------------------------------
    def sequence_index(self, seed: int, stratum: str, slot: int) -> int | None:
        """Which of the scheme's sequences allocation slot ``slot`` gets (None for ``random``)."""
        if self.sequences is None:
            return None
        nseq = len(self.sequences)
        if self.allocation == "alternating":
            return slot % nseq
        if self.allocation == "blocked":
            return (slot // self.block_size) % nseq
        key = self._stratum_keys[stratum] if self.within_strata else 0
        rng = np.random.Generator(
            np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(_PURPOSE_ALLOCATION, key, slot // nseq)))
        )
        return int(np.argsort(rng.random(nseq), kind="stable")[slot % nseq])

    # -- expansion --------------------------------------------------------------------------------
    def expand(self, *, seed: int, slot: int, stratum: str | None = None) -> Schedule:
        """The plan of the participant in allocation slot ``slot`` of ``stratum`` (see module docs)."""
        stratum = self._check(seed, slot, stratum)
        rng, sequence, order = self._start(seed, stratum, slot)
        placements = self._placements(rng, self.n_trials) if self.items else None  # type: ignore[arg-type]
        return self._finish(seed, stratum, slot, sequence, order, rng, placements)

    def expand_batch(self, *, seed: int, pairs: Sequence[tuple[str | None, int]]) -> list[Schedule]:
        """Plans of many ``(stratum, slot)`` participants; identical to :meth:`expand` for each.

        Faster for previews and benchmarks: the first batch of placement candidates of every
        participant is drawn from that participant's own generator, then ranked in one numpy call.
        """
        checked = [(self._check(seed, slot, stratum), slot) for stratum, slot in pairs]
        if not self.items:
            return [self.expand(seed=seed, slot=slot, stratum=stratum) for stratum, slot in checked]
        started = [self._start(seed, stratum, slot) for stratum, slot in checked]
        draws = np.stack([rng.random((self._place_batch, self.sites)) for rng, _, _ in started])  # type: ignore[union-attr]
        firsts = (np.argsort(draws, axis=2, kind="stable")[:, :, : len(self.items)] + 1).tolist()
        return [
            self._finish(seed, stratum, slot, sequence, order, rng,
                         self._placements(rng, self.n_trials, first=first))  # type: ignore[arg-type]
            for (stratum, slot), (rng, sequence, order), first in zip(checked, started, firsts, strict=True)
        ]

    def _start(self, seed: int, stratum: str, slot: int) -> tuple[np.random.Generator | None, int | None,
                                                                   tuple[str, ...]]:
        """The participant's generator (None when nothing is drawn), sequence index and condition order."""
        key = self._stratum_keys[stratum] if self.within_strata else 0
        # Only protocols that draw anything pay for a generator.
        rng = participant_rng(seed, key, slot) if self.needs_rng else None
        sequence = self.sequence_index(seed, stratum, slot)
        if sequence is None:
            perm = cbal.random_order(len(self.ordered), rng).tolist()  # type: ignore[arg-type]
            order = self.fixed + tuple(self.ordered[i] for i in perm)
        else:
            order = self.sequences[sequence]  # type: ignore[index]
        return rng, sequence, order

    def _finish(self, seed: int, stratum: str, slot: int, sequence: int | None, order: tuple[str, ...],
                rng: np.random.Generator | None, placements: list[tuple[tuple[str, int], ...]] | None) -> Schedule:
        skeleton = self._skeletons.get(order)
        if skeleton is None:
            skeleton = self._skeletons[order] = self._skeleton(order)
        orientations = self._orientations(rng, skeleton) if self.orient_choices else None  # type: ignore[arg-type]
        if placements is None and orientations is None:
            entries = self._plain_entries.get(order)
            if entries is None:
                entries = self._plain_entries[order] = tuple(
                    PlanEntry(t, p, b, c, r, None, None, tl, fam, brk, after)
                    for t, p, b, c, r, tl, fam, brk, after in skeleton
                )
        else:
            entries = tuple(
                PlanEntry(t, p, b, c, r, None if placements is None else placements[t - 1],
                          None if orientations is None else orientations[t - 1], tl, fam, brk, after)
                for t, p, b, c, r, tl, fam, brk, after in skeleton
            )
        return Schedule(
            protocol_id=self._protocol_id,
            protocol_sha256=self._protocol_sha256,
            algorithm_version=SCHEDULE_ALGORITHM_VERSION,
            seed=int(seed),
            stratum=stratum,
            slot=int(slot),
            sequence=sequence,
            order=tuple(order),
            questionnaires_start=self.q_start,
            entries=entries,
        )

    def _skeleton(self, order: tuple[str, ...]) -> tuple[tuple[Any, ...], ...]:
        """The participant-independent fields of every trial for one condition order.

        Rows are (trial, position, block, condition, repetition, time limit, familiarisation, break,
        questionnaires after).
        """
        rows = []
        trial = 0
        blocks = [order[::-1] if (self.block_order == "reverse" and b % 2 == 1) else order for b in range(self.blocks)]
        for b, this in enumerate(blocks):
            for p, condition in enumerate(this, start=1):
                for r in range(1, self.repetitions + 1):
                    first_of_condition = r == 1
                    fam = self.fam_s if first_of_condition and (self.fam_each or trial == 0) else None
                    if trial == 0:
                        brk = 0.0
                    elif self.break_each_trial or first_of_condition:
                        brk = self.break_s
                    else:
                        brk = 0.0
                    end_condition = r == self.repetitions
                    end_block = end_condition and p == len(this)
                    after = self._after(condition, end_condition, end_block, end_block and b == len(blocks) - 1)
                    trial += 1
                    rows.append((trial, p, b + 1, condition, r, self.time_limit, fam, brk, after))
        return tuple(rows)

    def _check(self, seed: int, slot: int, stratum: str | None) -> str:
        if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
            raise UsageError(f"seed must be a non-negative integer, got {seed!r}")
        if not isinstance(slot, (int, np.integer)) or isinstance(slot, bool) or slot < 0:
            raise UsageError(f"slot must be a non-negative integer, got {slot!r}")
        if stratum is None:
            if len(self.strata) != 1:
                raise UsageError(f"this protocol has strata {', '.join(self.strata)}; say which one")
            return self.strata[0]
        if stratum not in self._stratum_keys:
            raise UsageError(f"unknown stratum {stratum!r}; this protocol has {', '.join(self.strata)}")
        return stratum

    def _after(self, condition: str, end_condition: bool, end_block: bool, end_plan: bool) -> tuple[str, ...]:
        out = []
        for instrument, when, only in self._admins:
            if only is not None and condition not in only:
                continue
            if (
                when == "after_trial"
                or (when == "after_condition" and end_condition)
                or (when == "after_block" and end_block)
                or (when == "end" and end_plan)
            ):
                out.append(instrument)
        return tuple(out)

    def _placements(self, rng: np.random.Generator, n_trials: int,
                    first: list[list[int]] | None = None) -> list[tuple[tuple[str, int], ...]]:
        """Item→site placements per trial, each different from the previous one by the protocol's rule.

        Candidates come in batches of ``_place_batch`` rows of uniforms, ranked per row (the first
        ``len(items)`` ranks are the 1-based sites); ``first`` is the first batch already ranked.
        """
        k, n, rule, items = len(self.items), self.sites, self.place_rule, self.items
        out: list[tuple[tuple[str, int], ...]] = []
        previous: list[int] | None = None
        while len(out) < n_trials:
            if first is not None:
                candidates, first = first, None
            else:
                candidates = (np.argsort(rng.random((self._place_batch, n)), axis=1, kind="stable")[:, :k]
                              + 1).tolist()
            for cand in candidates:
                if previous is not None:
                    if rule == "assignment" and cand == previous:
                        continue
                    if rule == "every_item" and not all(map(ne, cand, previous)):
                        continue
                out.append(tuple(zip(items, cand, strict=True)))
                previous = cand
                if len(out) == n_trials:
                    break
        return out

    def _orientations(self, rng: np.random.Generator, skeleton: tuple[tuple[Any, ...], ...]) -> list[float]:
        """Orientation per trial, drawn per condition (position), block or trial."""
        m = len(self.orient_choices)
        draws = rng.random(len(skeleton)).tolist()
        out: list[float] = []
        previous: int | None = None
        angle = 0.0
        for i, (_, position, block, _, repetition, *_rest) in enumerate(skeleton):
            new = (
                self.orient_per == "trial"
                or (self.orient_per == "condition" and repetition == 1)
                or (self.orient_per == "block" and repetition == 1 and position == 1)
            )
            if new:
                u = draws[i]
                if self.orient_differ and previous is not None:
                    idx = int(u * (m - 1))
                    idx = idx + 1 if idx >= previous else idx
                else:
                    idx = int(u * m)
                previous = idx
                angle = float(self.orient_choices[idx])
            del block
            out.append(angle)
        return out


def expand_schedule(protocol: Protocol, *, seed: int, slot: int, stratum: str | None = None) -> Schedule:
    """Expand the plan of the participant in allocation ``slot`` (0-based) of ``stratum``.

    Parameters
    ----------
    protocol
        A loaded protocol (:func:`studyctl.protocol.load_protocol`).
    seed
        The study's schedule seed (non-negative integer), stored with the plan.
    slot
        0-based allocation slot within the stratum (or the study, if not ``within_strata``).
    stratum
        Stratum id; may be omitted when the protocol has a single stratum.

    Returns
    -------
    Schedule
        Identical for identical arguments and :data:`SCHEDULE_ALGORITHM_VERSION`.
    """
    return Planner(protocol).expand(seed=seed, slot=slot, stratum=stratum)


def allocate_strata(protocol: Protocol, participants: int) -> list[tuple[str, int]]:
    """(stratum, slot) for participants 1..N of a simulated enrollment.

    Strata get participants in proportion to their ``target_n`` (equal shares without targets, largest
    remainders first), enrolled stratum after stratum. Slots count within each stratum, or across the
    study when ``counterbalance.within_strata`` is false.
    """
    if participants < 0:
        raise UsageError(f"number of participants must be >= 0, got {participants}")
    strata = protocol.participants.strata
    weights = [s.target_n or 1 for s in strata] if any(s.target_n for s in strata) else [1] * len(strata)
    total = sum(weights)
    exact = [participants * w / total for w in weights]
    counts = [int(x) for x in exact]
    for i in sorted(range(len(strata)), key=lambda i: -(exact[i] - counts[i]))[: participants - sum(counts)]:
        counts[i] += 1
    pairs = [(s.id, slot) for s, count in zip(strata, counts, strict=True) for slot in range(count)]
    if not protocol.counterbalance.within_strata:  # one slot sequence across the whole study
        pairs = [(stratum, index) for index, (stratum, _) in enumerate(pairs)]
    return pairs


def expand_many(protocol: Protocol, *, seed: int, participants: int) -> list[Schedule]:
    """Plans of participants 1..N allocated by :func:`allocate_strata` (for previews and benchmarks)."""
    return Planner(protocol).expand_batch(seed=seed, pairs=allocate_strata(protocol, participants))


def schedule_balance(protocol: Protocol, schedules: Iterable[Schedule]) -> cbal.BalanceReport:
    """Position and carry-over counts of the block-1 condition orders of ``schedules``."""
    fixed = tuple(protocol.counterbalance.fixed_first)
    return cbal.balance_report(
        [(s.stratum, s.order) for s in schedules], protocol.condition_ids, protocol.stratum_ids, fixed
    )


def schedule_rows(schedules: Sequence[Schedule]) -> pd.DataFrame:
    """Rows participant, stratum, slot, trial, position, block, condition, repetition, placement, orientation_deg.

    ``participant`` is the 1-based order of the schedule in ``schedules``; ``slot`` is 1-based too, the number
    ``studyctl enroll`` prints (the stored :attr:`Schedule.slot` counts from 0).
    """
    import pandas as pd

    rows = []
    for number, schedule in enumerate(schedules, start=1):
        for e in schedule.entries:
            rows.append((number, schedule.stratum, schedule.slot + 1, e.trial, e.position, e.block, e.condition,
                         e.repetition, format_placement(e.placement), e.orientation_deg))
    return pd.DataFrame(rows, columns=["participant", "stratum", "slot", "trial", "position", "block", "condition",
                                       "repetition", "placement", "orientation_deg"])
