"""Enrollment: give the next participant a pseudonymous code, an allocation slot and a stored plan.

All of it happens in one write transaction holding the study's enrollment lock (SQLite: ``BEGIN
IMMEDIATE``; PostgreSQL: an advisory lock), so two coordinators enrolling at the same moment never get
the same code or slot.

Slots are counted within the participant's stratum (or across the study when
``counterbalance.within_strata`` is false). With ``participants.replace_withdrawn`` a withdrawn
participant's slot is free again and goes to the next enrollee (the lowest free slot): balance then
counts participants who completed or are still taking part, not every assignment ever made.
"""

from __future__ import annotations

import secrets
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from sqlalchemy import select

from studyctl.errors import IntegrityError, NotFoundError, UsageError
from studyctl.protocol.loader import load_protocol_text
from studyctl.protocol.schedule import SCHEDULE_ALGORITHM_VERSION, Planner
from studyctl.protocol.schema import Protocol
from studyctl.protocol.stored_plan import Schedule
from studyctl.store.audit import append_audit
from studyctl.store.identity import CODE_ALPHABET, random_code
from studyctl.store.models import Participant, Study
from studyctl.suggest import nearest

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)

CODE_LENGTH = 5
OVER_TARGET_ACTION = "participant.over_target"
_CODE_TRIES = 100


@dataclass(frozen=True)
class Enrollment:
    """A new participant: code, stratum, 0-based allocation slot, sequence and the stored plan."""

    participant_id: int
    code: str
    stratum: str
    slot: int
    schedule: Schedule
    over_target: str | None = None  # the target the enrollment went past on purpose (audited), else None

    @property
    def order(self) -> tuple[str, ...]:
        """The condition order of block 1."""
        return self.schedule.order

    @property
    def sequence(self) -> int | None:
        """Index of the scheme's sequence this slot received (None for random orders)."""
        return self.schedule.sequence

    def to_frame(self) -> pd.DataFrame:
        """The participant's plan, one row per trial, with ``code`` and ``stratum`` columns first."""
        frame = self.schedule.to_frame()
        frame.insert(0, "stratum", self.stratum)
        frame.insert(0, "code", self.code)
        return frame


def study_protocol(study: Any) -> Protocol:
    """The protocol snapshot stored with a study, checked against its stored sha256."""
    if not study.protocol_text:
        raise UsageError(f"study {study.name!r} has no protocol; create the study with "
                         "`studyctl init DIR --protocol NAME_OR_FILE`")
    protocol = load_protocol_text(study.protocol_text, f"{study.protocol_name or 'protocol'} (stored in the study)")
    if study.protocol_sha256 and protocol.sha256 != study.protocol_sha256:
        raise IntegrityError(f"the protocol stored with study {study.name!r} no longer matches its sha256 "
                             f"({protocol.sha256[:12]} ≠ {study.protocol_sha256[:12]}); the database was edited")
    return protocol


def choose_stratum(protocol: Protocol, group: str | None) -> str:
    """The stratum a ``--group`` names (or the only stratum); UsageError lists the valid ones."""
    strata = list(protocol.stratum_ids)
    if group is None:
        if len(strata) == 1:
            return strata[0]
        raise UsageError(f"this study has groups {', '.join(strata)}; say which with --group")
    if group not in strata:
        hint = nearest(group, strata)
        raise UsageError(f"unknown group {group!r}; this study has {', '.join(strata)}"
                         + (f" (did you mean {hint!r}?)" if hint else ""))
    return group


def next_slot(taken: list[tuple[int | None, str]], replace_withdrawn: bool) -> int:
    """The next allocation slot given the ``(slot, status)`` of participants in the same slot domain.

    Without ``replace_withdrawn`` every assignment counts: the next slot follows the highest ever
    given. With it, slots of withdrawn participants are free again and the lowest free slot is used.
    """
    slots = [s for s, status in taken if s is not None and (not replace_withdrawn or status != "withdrawn")]
    if not replace_withdrawn:
        return max(slots) + 1 if slots else 0
    used = set(slots)
    slot = 0
    while slot in used:
        slot += 1
    return slot


def new_code(prefix: str, existing: set[str], token: Callable[[str], str] = secrets.choice) -> str:
    """A random pseudonymous code ``PREFIX-XXXXX`` not in ``existing`` (not derived from anything)."""
    for _ in range(_CODE_TRIES):
        code = random_code(prefix, CODE_LENGTH, token=token)
        if code not in existing:
            return code
    raise IntegrityError(f"could not draw an unused participant code after {_CODE_TRIES} tries")


def enroll(store: Any, group: str | None = None, *, study: str | None = None, code: str | None = None,
           over_target: bool = False) -> Enrollment:
    """Enroll the next participant of a study and store their plan.

    Parameters
    ----------
    store
        An open :class:`studyctl.store.StudyStore`.
    group
        The stratum (between-subject group) to enroll into; optional when the protocol has one stratum.
    study
        Study name; default the only study in the database.
    code
        A code to use instead of a random one (must be unused in the study).
    over_target
        Enroll even when the stratum's (or study's) target size is reached by participants who have not
        withdrawn; without it that is a :class:`UsageError`.

    Returns
    -------
    Enrollment
        Code, stratum, slot and the stored :class:`Schedule` (seeded by the study's master seed).
    """
    target = store.get_study(study)
    protocol = study_protocol(target)
    stratum = choose_stratum(protocol, group)
    planner = Planner(protocol)
    within = protocol.counterbalance.within_strata
    with store.in_transaction(lock=f"enroll:{target.id}") as tx:
        fresh = tx.get(Study, target.id)
        if fresh is None:  # pragma: no cover - deleted between the two reads
            raise NotFoundError(f"study {target.name!r} disappeared")
        rows = tx.execute(
            select(Participant.code, Participant.stratum, Participant.sequence_slot, Participant.status)
            .where(Participant.study_id == target.id)
        ).all()
        existing = {r.code for r in rows}
        past = _target_reached(protocol, stratum, rows)
        if past is not None and not over_target:
            raise UsageError(f"{past}; add --over-target to enroll one more on purpose")
        domain = [(r.sequence_slot, r.status) for r in rows if not within or r.stratum == stratum]
        slot = next_slot(domain, protocol.participants.replace_withdrawn)
        if code is not None and code in existing:
            raise UsageError(f"participant code {code!r} is already enrolled in this study; codes must be unique")
        chosen = code if code is not None else new_code(protocol.participants.code_prefix, existing)
        schedule = planner.expand(seed=int(fresh.seed), slot=slot, stratum=stratum)
        participant = store.add_participant(
            target.id,
            chosen,
            stratum=stratum,
            sequence_slot=slot,
            schedule=schedule.to_json(),
            schedule_seed=int(fresh.seed),
            schedule_algorithm_version=str(SCHEDULE_ALGORITHM_VERSION),
            tx=tx,
        )
        participant_id = participant.id
        if past is not None:  # on purpose: a record of its own (in the export's records), same transaction
            append_audit(tx, OVER_TARGET_ACTION, entity="participant", entity_id=participant_id,
                         details={"code": chosen, "stratum": stratum, "target": past})
    return Enrollment(participant_id=participant_id, code=chosen, stratum=stratum, slot=slot, schedule=schedule,
                      over_target=past)


def _target_reached(protocol: Protocol, stratum: str, rows: list) -> str | None:
    """Which target size (the stratum's, else the study's) one more enrollment would pass, or None (withdrawn people
    do not count)."""
    active = [r for r in rows if r.status != "withdrawn"]
    target = next((s.target_n for s in protocol.participants.strata if s.id == stratum), None)
    in_stratum = sum(1 for r in active if r.stratum == stratum)
    if target is not None and in_stratum >= target:
        return f"group {stratum} has reached its target of {target} participants ({in_stratum} enrolled, not withdrawn)"
    total = protocol.participants.target_n
    if total is not None and len(active) >= total:
        return f"the study has reached its target of {total} participants ({len(active)} enrolled, not withdrawn)"
    return None


def replan(protocol: Protocol, participant: Any) -> Schedule:
    """Expand a stored participant's plan again from (protocol, schedule seed, stratum, slot).

    Raises :class:`IntegrityError` when the participant was planned by another algorithm version
    or the stored plan differs from the re-expanded one (the plan was edited).
    """
    version = str(participant.schedule_algorithm_version)
    if version != str(SCHEDULE_ALGORITHM_VERSION):
        raise IntegrityError(f"participant {participant.code} was planned with schedule algorithm {version}; this "
                             f"studyctl has {SCHEDULE_ALGORITHM_VERSION}: use the stored plan, do not re-expand")
    schedule = Planner(protocol).expand(seed=int(participant.schedule_seed), slot=int(participant.sequence_slot),
                                        stratum=participant.stratum)
    if participant.schedule is not None and schedule.to_json() != participant.schedule:
        raise IntegrityError(f"the stored plan of participant {participant.code} differs from its re-expansion; "
                             "the stored plan was edited")
    return schedule


__all__ = [
    "CODE_ALPHABET",
    "CODE_LENGTH",
    "Enrollment",
    "choose_stratum",
    "enroll",
    "new_code",
    "next_slot",
    "replan",
    "study_protocol",
]
