"""The :class:`~studyctl.engine.recorder.Recorder` that writes a session to the study database.

Layout in the store (see :mod:`studyctl.store.models`):

* the session plan: event ``session_plan`` (payload ``{"plan": …}``), later ``plan_amended`` events;
* one ``trial`` row per planned trial (status ``planned``) created with the session, one more row per
  repeat attempt (``replaces_trial_id`` → the aborted row); ``outcome`` holds ``step`` (plan step
  position) and ``attempt`` from the start, the loop's outcome at the end;
* step transitions: events ``step_enter`` / ``step_done`` with ``{"position": …}``;
* event times (``t_mono``): events tagged with a trial (``scan``, ``report``, safety events …) carry the
  trial time in seconds since the trial loop started; all others the session time in seconds;
* answers: ``questionnaire_response`` rows with ``context = "step:<position>"`` and an ``answer`` event
  (with the response time) in the same transaction;
* samples: :class:`~studyctl.store.samples.SampleWriter` chunks (flushed at least every second).

The recorder mirrors the session's state in memory (it is the only writer of its session) and
rebuilds it from the database in :meth:`StoreRecorder.load`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from sqlalchemy import select

from studyctl.engine.plan import SessionPlan
from studyctl.engine.recorder import MEMORY_EVENT, SessionState, TrialRecord
from studyctl.engine.sample_buffer import StoreSamples
from studyctl.errors import NotFoundError, SessionError
from studyctl.store import StudyStore
from studyctl.store.lease import SessionLeaseHandle, current_holder, owner_alive, take_lease
from studyctl.store.models import Event, Participant, QuestionnaireResponse, Session, Trial, utcnow
from studyctl.store.records import SealMark, load_mark, seal_session
from studyctl.store.status import rehearsal_session_ids

PLAN_EVENTS = ("session_plan", "plan_amended")
# Events a participant produced (or that mark a fault) are fsynced at once; the rest ride on the next
# durable commit. Either way the database is always a consistent prefix of what happened.
DURABLE_EVENTS = frozenset({"scan", "report", "device_fault", "session_resumed", "coordinator_abort",
                            "coordinator_pause", "coordinator_mark_invalid"})


def _add_trial_row(store: StudyStore, tx, session_id: int, step, status: str, attempt: int,
                   replaces: int | None = None) -> Trial:
    """A trial row for a plan step; ``outcome`` starts with where in the plan it belongs."""
    row = store.add_trial(
        session_id, plan_position=int(step.trial_index or step.position), condition=step.condition,
        block=step.block, repetition=step.repetition, placement=step.data.get("placement"),
        time_limit_s=step.duration_s, status=status, replaces_trial_id=replaces,
        started_at=utcnow() if status == "running" else None, tx=tx,
    )
    store.update_trial(row.id, outcome={"step": step.position, "attempt": attempt}, tx=tx)
    return row


def _context(position: int) -> str:
    return f"step:{position}"


UNFINISHED = ("running", "paused", "interrupted")


def refuse_second_session(store: StudyStore, tx, participant: Participant) -> None:
    """Raise :class:`SessionError` if the participant already has a session: a participant takes part once.

    Run inside the write transaction that would create the session (SQLite ``BEGIN IMMEDIATE``, PostgreSQL
    with the participant row locked), so of concurrent starts exactly one passes. A session someone is
    running is refused with its lease holder (pid, host, since).
    """
    sessions = list(tx.scalars(select(Session).where(Session.participant_id == participant.id).order_by(Session.id)))
    if sessions:  # rehearsals (`studyctl run --rehearse`) are not taking part: any number, before or after
        rehearsals = rehearsal_session_ids(tx, [x.id for x in sessions])
        sessions = [x for x in sessions if x.id not in rehearsals]
    for sess in sessions:
        if sess.status == "completed":
            raise SessionError(f"participant {participant.code} already completed session {sess.id}; a participant "
                               "takes part once (see `studyctl status`, `studyctl export DIR`)")
    for sess in sessions:
        if sess.status in UNFINISHED:
            holder = current_holder(tx, sess.id)
            if holder is not None and owner_alive(store.db, holder) is not False:
                raise holder.refusal()
            left = " --take-over" if holder is not None else ""  # its process is gone but still holds the lease
            raise SessionError(f"participant {participant.code} has an unfinished session {sess.id} ({sess.status}); "
                               f"continue it with `studyctl resume {sess.id}{left}`")


class StoreRecorder:
    """A session's durable record in a :class:`~studyctl.store.StudyStore`.

    Create a new session with :meth:`create`, reopen one with :meth:`load`.
    """

    def __init__(self, store: StudyStore, state: SessionState, participant_id: int,
                 mark: SealMark | None = None) -> None:
        self.store = store
        # what of this session the audit chain already seals (every transaction here seals what it wrote)
        self._mark = mark or SealMark()
        self._state = state
        self.participant_id = participant_id
        self._pending: list[tuple[int | None, tuple[float, str, Mapping[str, Any]]]] = []
        # The session's lease when this process runs it (None for read-only use and internal tools).
        self.lease: SessionLeaseHandle | None = None

    def close(self) -> None:
        """Let go of the session's lease (if held)."""
        if self.lease is not None:
            lease, self.lease = self.lease, None
            lease.release()

    def _tx(self, durable: bool = True):
        """A write transaction of this session; checks first that this process still holds its lease."""
        return _LeasedTx(self, durable)

    @property
    def session_id(self) -> int:
        return self._state.session_id

    # -- creation / loading ------------------------------------------------------------------------
    @classmethod
    def create(
        cls,
        store: StudyStore,
        participant_id: int,
        plan: SessionPlan,
        *,
        seed: int,
        virtual: bool,
        site: str | None = None,
        population: Mapping[str, Any] | None = None,
        lease: bool = False,
        rehearsal: bool = False,
    ) -> StoreRecorder:
        """Start a new session: the session row, its plan and one planned row per trial, in one transaction.

        ``population`` (a virtual person's population record: name, version, sha256, traits) is stored as a
        ``population`` event in the same transaction. ``lease``: also refuse a participant who already has a
        session and take the new session's lease in the same transaction (what ``studyctl run`` does; release
        it with :meth:`close`).
        """
        handle = None
        with store.in_transaction() as tx:
            participant = tx.get(Participant, participant_id, with_for_update=lease)
            if participant is None:
                raise NotFoundError(f"no participant with id {participant_id}")
            code = participant.code
            if lease and not rehearsal:
                refuse_second_session(store, tx, participant)
            sess = store.start_session(participant_id, seed=seed, site=site, tx=tx)
            if lease:
                handle = take_lease(store.db, tx, sess.id)
            head = {"plan": plan.to_json(), "virtual": bool(virtual), **({"rehearsal": True} if rehearsal else {})}
            store.append_event(sess.id, "session_plan", head, t_mono=0.0, tx=tx)
            if population is not None:
                store.append_event(sess.id, "population", dict(population), t_mono=0.0, tx=tx)
            trials: list[TrialRecord] = []
            for step in plan.trials():
                row = _add_trial_row(store, tx, sess.id, step, "planned", 1)
                trials.append(TrialRecord(row.id, step.position, 1, "planned", condition=step.condition))
            if participant.status == "enrolled" and not rehearsal:  # a rehearsal is not taking part
                store.set_participant_status(participant_id, "active", tx=tx)
            mark = SealMark()
            sealed = seal_session(tx, sess.id, mark)
        if sealed:
            mark.fold(sealed)
        state = SessionState(session_id=sess.id, participant=code, seed=seed, status="running", plan=plan,
                             trials=trials, virtual=bool(virtual), rehearsal=bool(rehearsal))
        rec = cls(store, state, participant_id, mark)
        rec.lease = handle
        return rec

    @classmethod
    def load(cls, store: StudyStore, session_id: int) -> StoreRecorder:
        """Rebuild a session's state from the database (for resume, status and export)."""
        sess = store.get_session(session_id)
        with store.reading() as s:
            participant = s.get(Participant, sess.participant_id)
            events = s.execute(
                select(Event.kind, Event.payload, Event.t_mono, Event.trial_id)
                .where(Event.session_id == session_id).order_by(Event.seq)
            ).all()
            rows = list(s.scalars(select(Trial).where(Trial.session_id == session_id).order_by(Trial.id)))
            answers = s.execute(
                select(QuestionnaireResponse.context, QuestionnaireResponse.item, QuestionnaireResponse.code)
                .where(QuestionnaireResponse.session_id == session_id).order_by(QuestionnaireResponse.id)
            ).all()
            mark = load_mark(s, session_id)
        plan_json = None
        virtual = True
        rehearsal = False
        completed: set[int] = set()
        started: set[int] = set()
        last_t = 0.0
        memory = None
        for kind, payload, t_mono, trial_id in events:
            if kind in PLAN_EVENTS:
                plan_json = (payload or {}).get("plan")
                if kind == "session_plan":
                    virtual = bool((payload or {}).get("virtual", True))
                    rehearsal = bool((payload or {}).get("rehearsal", False))
            elif kind == "step_enter":
                started.add(int(payload["position"]))
            elif kind == "step_done":
                completed.add(int(payload["position"]))
            elif kind == MEMORY_EVENT:
                memory = dict((payload or {}).get("memory") or {})
            if trial_id is None and t_mono is not None:
                last_t = max(last_t, float(t_mono))
        if plan_json is None:
            raise SessionError(f"session {session_id} has no stored plan; it was not started by the session engine")
        plan = SessionPlan.from_json(plan_json)
        trials = []
        for r in rows:
            out = dict(r.outcome or {})
            if "step" not in out:
                continue
            trials.append(TrialRecord(r.id, int(out["step"]), int(out.get("attempt", 1)), r.status,
                                      r.invalid_reason or "", out, r.condition))
        state = SessionState(
            session_id=session_id, participant=participant.code, seed=int(sess.seed or 0), status=sess.status,
            plan=plan, completed=completed, started=started, trials=trials,
            answers={(int(c.split(":", 1)[1]), item): int(code) for c, item, code in answers
                     if c and c.startswith("step:")},
            resumes=int(sess.resume_count or 0), last_t=last_t, virtual=virtual, memory=memory,
            rehearsal=rehearsal,
        )
        return cls(store, state, participant.id, mark)

    # -- Recorder ----------------------------------------------------------------------------------
    def state(self) -> SessionState:
        return self._state

    def _flush_pending(self, tx) -> None:
        if not self._pending:
            return
        # keep order; group consecutive events of the same trial into one insert
        groups: list[tuple[int | None, list[tuple[float, str, Mapping[str, Any]]]]] = []
        for trial_id, ev in self._pending:
            if groups and groups[-1][0] == trial_id:
                groups[-1][1].append(ev)
            else:
                groups.append((trial_id, [ev]))
        for trial_id, evs in groups:
            self.store.append_events(self.session_id, evs, trial_id=trial_id, tx=tx)
        self._pending.clear()

    def _append(self, tx, kind: str, payload: Mapping[str, Any] | None, t: float | None, trial_id: int | None):
        self._flush_pending(tx)
        self.store.append_event(self.session_id, kind, _jsonable(payload or {}),
                                t_mono=float(t if t is not None else self._state.last_t), trial_id=trial_id, tx=tx)
        if t is not None and trial_id is None:
            self._state.last_t = max(self._state.last_t, float(t))

    def event(self, kind, payload=None, *, t=None, position=None, trial_id=None, commit=True, durable=None) -> None:
        """Append an event. Durable (fsynced) for answers-like kinds; otherwise committed so that it survives
        the process being killed, and made power-cut safe by the next durable commit (WAL keeps order)."""
        if durable is None:
            durable = kind in DURABLE_EVENTS
        body = dict(payload or {})
        if position is not None:
            body.setdefault("position", position)
        if not commit:
            self._pending.append((trial_id, (float(t if t is not None else 0.0), kind, _jsonable(body))))
            if len(self._pending) < 256:
                return
        with self._tx(durable) as tx:
            if commit:
                self._append(tx, kind, body, t, trial_id)
            else:
                self._flush_pending(tx)

    def set_status(self, status: str, reason: str = "") -> None:
        with self._tx() as tx:
            fields: dict[str, Any] = {"status": status}
            if status in ("completed", "aborted"):
                fields["ended_at"] = utcnow()
            self.store.update_session(self.session_id, tx=tx, **fields)
            self._append(tx, "session_status", {"status": status, "reason": reason}, None, None)
            if status == "completed" and not self._state.rehearsal:
                self.store.set_participant_status(self.participant_id, "completed", tx=tx)
        self._state.status = status

    def step_started(self, position: int, t: float) -> None:
        # not fsynced: if it is lost in a power cut, so is everything after it, and the step simply reruns
        self.event("step_enter", {"position": position}, t=t, durable=False)
        self._state.started.add(position)

    def step_completed(self, position: int, t: float, summary=None) -> None:
        with self._tx() as tx:
            self._append(tx, "step_done", {**dict(summary or {}), "position": position}, t, None)
        self._state.completed.add(position)

    def trial_started(self, position: int, attempt: int, t: float, info) -> int:
        step = self._state.plan.step(position)
        planned = [r for r in self._state.trials if r.position == position and r.status == "planned"]
        outcome = {"step": position, "attempt": attempt}
        with self._tx(False) as tx:
            self._append(tx, "step_enter", {"position": position}, t, None)
            if planned:
                tid = planned[0].trial_id
                self.store.update_trial(tid, status="running", started_at=utcnow(), outcome=outcome, tx=tx)
            else:
                previous = self._state.attempts(position)
                replaces = previous[-1].trial_id if previous else None
                tid = _add_trial_row(self.store, tx, self.session_id, step, "running", attempt, replaces=replaces).id
            self._append(tx, "trial_start", {**dict(info), "position": position, "trial_id": tid}, t, None)
        self._state.started.add(position)
        self._state.trials = [r for r in self._state.trials if r.trial_id != tid]
        self._state.trials.append(TrialRecord(tid, position, attempt, "running", "", outcome, step.condition))
        self._state.trials.sort(key=lambda r: r.trial_id)
        return tid

    def trial_finished(self, trial_id, status, outcome, reports, *, position, t, reason="", complete_step=True):
        with self._tx() as tx:
            self._flush_pending(tx)
            out = _jsonable(dict(outcome))
            self.store.update_trial(
                trial_id, status=status, ended_at=utcnow(), outcome=out, timed_out=bool(outcome.get("timed_out")),
                invalid_reason=reason or None, tx=tx,
            )
            for rep in reports:
                body = {k: v for k, v in rep.items() if k != "t"}
                self.store.record_location_report(trial_id, t=float(rep.get("t") or 0.0), payload=body, tx=tx)
            self._append(tx, "trial_end", {"status": status, "reason": reason, "trial_id": trial_id, **out}, t, None)
            if complete_step:
                self._append(tx, "step_done", {"position": position, "trial_id": trial_id, "status": status}, t, None)
        self._state.set_trial(trial_id, status, reason, out)
        if complete_step:
            self._state.completed.add(position)

    def mark_trial(self, trial_id: int, status: str, reason: str) -> None:
        with self._tx() as tx:
            self.store.update_trial(trial_id, status=status, invalid_reason=reason, tx=tx)
            self._append(tx, "trial_marked", {"trial_id": trial_id, "status": status, "reason": reason}, None, None)
        self._state.set_trial(trial_id, status, reason)

    def samples(self, trial_id: int, channels: list[str]) -> StoreSamples:
        # a writer that lost the session's lease (another process took it over) stores no further samples
        return StoreSamples(self.store, trial_id, guard=self.lease.verify if self.lease is not None else None)

    def answer(self, position, instrument, version, item, code, response_time_s) -> None:
        with self._tx() as tx:
            self.store.record_response(
                self.participant_id, instrument=instrument, instrument_version=version, item=item, code=int(code),
                session_id=self.session_id, context=_context(position), tx=tx,
            )
            self._append(tx, "answer", {"position": position, "instrument": instrument, "version": version,
                                        "item": item, "code": int(code), "response_time_s": response_time_s},
                         None, None)
        self._state.answers[(position, item)] = int(code)

    def amend_plan(self, plan: SessionPlan, reason: str) -> None:
        known = {r.position for r in self._state.trials}
        new_rows: list[TrialRecord] = []
        with self._tx() as tx:
            self._append(tx, "plan_amended", {"plan": plan.to_json(), "reason": reason}, None, None)
            for step in plan.trials():
                if step.position in known:
                    continue
                prev = [r for r in self._state.trials if r.position == step.replaces]
                row = _add_trial_row(self.store, tx, self.session_id, step, "planned", 1,
                                     replaces=prev[-1].trial_id if prev else None)
                new_rows.append(TrialRecord(row.id, step.position, 1, "planned", condition=step.condition))
        self._state.plan = plan
        self._state.trials.extend(new_rows)

    def audit(self, action: str, detail) -> None:
        with self._tx() as tx:
            if action == "note":  # a coordinator's note on the running trial: the same row as `studyctl note`
                self.store.audit("note", entity="trial", entity_id=detail["trial_id"],
                                 details=_jsonable(dict(detail)), tx=tx)
            else:
                self.store.audit(f"session.{action}" if "." not in action else action, entity="session",
                                 entity_id=self.session_id, details=_jsonable(dict(detail)), tx=tx)
            if action == "session_resumed":
                self.store.update_session(self.session_id, resume_count=self._state.resumes + 1, tx=tx)
        if action == "session_resumed":
            self._state.resumes += 1


class _LeasedTx:
    def __init__(self, rec: StoreRecorder, durable: bool) -> None:
        self._cm = rec.store.in_transaction(durable=durable)
        self._rec = rec

    def __enter__(self):
        tx = self._tx = self._cm.__enter__()
        if self._rec.lease is not None:
            try:
                self._rec.lease.verify(tx)
            except BaseException as exc:
                self._cm.__exit__(type(exc), exc, exc.__traceback__)
                raise
        return tx

    def __exit__(self, exc_type, exc, tb):
        sealed = None
        if exc_type is None:
            try:
                sealed = seal_session(self._tx, self._rec.session_id, self._rec._mark)
            except BaseException as err:
                self._cm.__exit__(type(err), err, err.__traceback__)
                raise
        suppress = self._cm.__exit__(exc_type, exc, tb)
        if sealed:
            self._rec._mark.fold(sealed)
        return suppress


def _jsonable(value: Any) -> Any:
    """Plain JSON types (numpy scalars → Python; inf/nan → None; tuples → lists)."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "item") and callable(value.item) and not isinstance(value, (str, bytes)):
        try:
            value = value.item()
        except (TypeError, ValueError):
            return str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)
