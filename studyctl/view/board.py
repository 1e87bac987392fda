"""The coordinator's page: what the coordinator watches during a session, live and read-only.

Served beside the participant view by the same server (its own secret URL, ``/c/<token>/``; the participant's
screen cannot reach it), and fed from three places, each by the party allowed to touch it:

* the **engine thread** (through :class:`~studyctl.view.frontend.ViewUI`) publishes the session's progress at
  every step: where in the protocol it is, the current step and its condition (the coordinator may see the
  condition code; the participant's page never gets it), trials done and left, attempts aborted or invalid,
  the running timer; and each trial-loop event as it happens (device faults and recoveries, safety limits);
* the **trial loop** only advances the tick the participant view already keeps (trial time, when, count);
* the **server thread** that answers the page builds the snapshot: loop rate measured between snapshots,
  how long ago the last tick was, the participant screens, and, at most every :data:`STORE_EVERY_S`, the
  session's lease owner and the coordinator's notes read from the study database (a note added with
  ``studyctl note`` in another terminal shows up here).

Nothing on the page can change the session: the server refuses anything but GET under ``/c/``.
"""

from __future__ import annotations

import collections
import json
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import select

from studyctl.engine.plan import Step

# The store is read at most this often (the page polls twice a second; a session's writer must not feel it).
STORE_EVERY_S = 2.0
# The whole study's progress (every participant) at most this often.
STUDY_EVERY_S = 6.0
STUDY_PEOPLE_SHOWN = 200
GAPS_SHOWN = 8  # dropped samples and missing data listed on the page (the totals count them all)
# Trial-loop events kept for the page (newest last).
EVENTS_KEPT = 12
# A loop tick older than this while a trial runs is shown as a stall.
STALL_S = 0.25
NOTES_KEPT = 20


def _iso(value: Any) -> str | None:
    if isinstance(value, datetime):
        return value.astimezone(UTC).isoformat(timespec="seconds")
    return None if value is None else str(value)


def progress_of(state: Any, step: Step | None) -> dict[str, Any]:
    """The session's place in its protocol (built on the engine thread from its own state)."""
    plan = state.plan
    steps = list(plan.steps)
    completed = set(state.completed)
    trial_steps = [s for s in steps if s.kind == "trial"]
    done = sum(1 for s in trial_steps if s.position in completed)
    if step is None:
        step = next((s for s in steps if s.position not in completed), None)
    attempts = Counter(t.status for t in state.trials if t.status != "planned")
    current = step.position if step is not None else None
    rows = [{"position": s.position, "kind": s.kind, "condition": s.condition, "trial": s.trial_index,
             "label": s.label(),
             "state": "done" if s.position in completed else "current" if s.position == current else "todo"}
            for s in steps]
    cond = plan.conditions.get(step.condition) if step is not None and step.condition else None
    return {
        "session_id": state.session_id,
        "participant": state.participant,
        "virtual": bool(state.virtual),
        "rehearsal": bool(getattr(state, "rehearsal", False)),
        "resumes": int(state.resumes),
        "steps_total": len(steps),
        "steps_done": sum(1 for s in steps if s.position in completed),
        "step": None if step is None else {
            "position": step.position, "kind": step.kind, "label": step.label(), "trial": step.trial_index,
            "block": step.block, "repetition": step.repetition,
            "time_limit_s": step.duration_s if step.kind == "trial" else None,
        },
        "condition": None if cond is None else {
            "code": cond.id, "label": cond.label, "controller": cond.controller, "visual": cond.visual,
            "manual": bool(cond.manual), "view_label": cond.view_label,
        },
        "trials": {"planned": len(trial_steps), "done": done, "left": len(trial_steps) - done,
                   "completed": attempts.get("completed", 0), "aborted": attempts.get("aborted", 0),
                   "invalid": attempts.get("invalid", 0)},
        "steps": rows,
        "device": _device(plan, bool(state.virtual), bool(getattr(state, "rehearsal", False))),
    }


def _device(plan: Any, virtual: bool, rehearsal: bool) -> dict[str, Any]:
    ref = plan.simulated_device if virtual else (plan.hardware_device or plan.simulated_device)
    name = (ref or {}).get("plugin") if isinstance(ref, Mapping) else None
    kind = "simulated" if virtual or not plan.hardware_device else "emulated" if rehearsal else "hardware"
    return {"plugin": name, "kind": kind}


def _copy(items: Any) -> list[Any]:
    """A list of a deque another thread appends to (iterating one that changes raises; try again)."""
    for _ in range(5):
        try:
            return list(items)
        except RuntimeError:
            continue
    return []


def _short_error(exc: BaseException) -> str:
    """What the page says when a read failed: the error's kind and the first line of its message, at most 200
    characters (an empty message gives the kind alone)."""
    lines = str(exc).splitlines()
    return f"{type(exc).__name__}: {lines[0][:200] if lines else ''}"


class CoordinatorBoard:
    """The coordinator page's state (see the module docstring for who writes what).

    Parameters
    ----------
    hub
        The participant view's hub (what the participant's screen shows, the loop's latest tick, the screens).
    clock
        ``time.perf_counter`` (the hub's clock).
    """

    def __init__(self, hub: Any, *, clock: Callable[[], float] = time.perf_counter) -> None:
        self.hub = hub
        self.clock = clock
        self.started = clock()
        self.started_wall = datetime.now(UTC)
        # -- engine thread (reference swaps and deque appends only) ------------------------------------
        self.progress: dict[str, Any] | None = None
        self.phase: dict[str, Any] = {"kind": "waiting", "since": clock()}
        self.events: collections.deque[dict[str, Any]] = collections.deque(maxlen=EVENTS_KEPT)
        self.trial_counts: Counter[str] = Counter()
        self.session_counts: Counter[str] = Counter()
        self.fault_active: dict[str, Any] | None = None
        self.rate_hz: float | None = None
        self._store: Any = None
        self._session_id: int | None = None
        # -- server threads ---------------------------------------------------------------------------
        self._lock = threading.Lock()
        self._ticks: collections.deque[tuple[float, int]] = collections.deque(maxlen=16)
        self._stored: dict[str, Any] = {"lease": None, "notes": [], "read_at": None, "error": None}
        self._stored_at = -1e9
        self._study_at = -1e9
        self._study_name: str | None = None
        self._participant_id: int | None = None
        self.polls = 0  # snapshots served (the bench waits for the page's first)
        self._erase_scan = 0  # erasure rows read up to this audit id
        self._erased_until = 0  # notes at or before this audit id are about an erased session of the same id

    # ============================================================== engine thread
    def bind(self, recorder: Any) -> None:
        """Where the session is recorded (for the lease and notes); a recorder without a store is fine."""
        self._store = getattr(recorder, "store", None)
        self._participant_id = getattr(recorder, "participant_id", None)
        try:
            self._session_id = int(recorder.session_id)
        except (AttributeError, TypeError, ValueError):
            self._session_id = None

    def publish(self, state: Any, step: Step | None, phase: str, **detail: Any) -> None:
        """The session entered ``phase`` (instructions, timer, item, trial_ready, trial, trial_over, …) of ``step``."""
        try:
            self.progress = progress_of(state, step)
        except AttributeError:  # a recorder without a session state (tests, tools): keep the last one
            pass
        if phase == "trial":
            self.trial_counts = Counter()
            self.fault_active = None
            self.rate_hz = None
        self.phase = {"kind": phase, "since": self.clock(), **detail}

    def trial_event(self, t: float, kind: str, payload: Mapping[str, Any]) -> None:
        """A trial-loop event as it happens (device faults and recoveries, safety limits, scans …)."""
        if kind == "trial_loop_start":
            rate = payload.get("rate_hz")
            self.rate_hz = float(rate) if isinstance(rate, (int, float)) else None
            return
        if kind in ("scan", "report"):  # from the view, the terminal or a virtual participant alike
            self.trial_counts[kind + "s"] += 1
            return
        if kind in ("device_fault", "device_recovered", "safety"):
            self.trial_counts[kind] += 1
            self.session_counts[kind] += 1
            missed = payload.get("missed")  # a missed deadline says how many ticks came late
            if isinstance(missed, (int, float)) and missed > 0:
                self.trial_counts["late_ticks"] += int(missed)
                self.session_counts["late_ticks"] += int(missed)
            entry = {"t": round(float(t), 3), "kind": kind,
                     "rule": str(payload.get("rule", payload.get("error", ""))),
                     "channel": payload.get("channel"), "state": payload.get("state"), "wall": time.time()}
            self.events.append(entry)
            if kind == "device_fault":
                self.fault_active = entry
            elif kind == "device_recovered":
                self.fault_active = None

    # ============================================================== server threads
    def _read_store(self) -> None:
        now = self.clock()
        if self._store is None or self._session_id is None or now - self._stored_at < STORE_EVERY_S:
            return
        self._stored_at = now
        from studyctl.store.lease import lease_info  # noqa: PLC0415 (only when a store is bound)
        from studyctl.store.models import AuditLog  # noqa: PLC0415

        sid = self._session_id
        try:
            with self._store.reading() as tx:
                lease = lease_info(tx, sid)
                self._erasures_seen(tx, AuditLog)
                rows = list(tx.execute(select(AuditLog.at, AuditLog.actor, AuditLog.entity, AuditLog.details)
                                       .where(AuditLog.action == "note", AuditLog.id > self._erased_until)
                                       .order_by(AuditLog.id.desc()).limit(500)))
        except Exception as exc:  # the page says it could not read; the session itself is not disturbed
            self._stored = {**self._stored, "error": _short_error(exc)}
            return
        notes = []
        for at, actor, entity, details in rows:
            try:
                d = json.loads(details)
            except ValueError:
                continue
            if d.get("session_id") == sid:
                notes.append({"at": at, "actor": actor, "on": "trial" if entity == "trial" else "session",
                              "trial_id": d.get("trial_id"), "text": str(d.get("text", ""))})
            if len(notes) >= NOTES_KEPT:
                break
        study = self._stored.get("study")
        if now - self._study_at >= STUDY_EVERY_S:
            self._study_at = now
            study = self._read_study()
        if lease is not None:
            lease = {"pid": lease["pid"], "host": lease["host"], "since": _iso(lease["since"]),
                     "heartbeat_age_s": round((datetime.now(UTC) - lease["heartbeat_at"]).total_seconds(), 1)}
        self._stored = {"lease": lease, "notes": notes, "read_at": datetime.now(UTC).isoformat(timespec="seconds"),
                        "error": None, "study": study}

    def _read_study(self) -> dict[str, Any] | None:
        """Every participant's progress by condition, the balance so far, dropped samples and missing data (what
        ``studyctl status`` shows)."""
        from studyctl.engine.data_gaps import data_gaps  # noqa: PLC0415 (only when a store is bound)
        from studyctl.engine.progress import study_progress  # noqa: PLC0415
        from studyctl.store.models import Participant, Study  # noqa: PLC0415

        try:
            if self._study_name is None:
                with self._store.reading() as tx:
                    self._study_name = tx.scalar(select(Study.name).join(Participant, Participant.study_id == Study.id)
                                                 .where(Participant.id == self._participant_id))
            if self._study_name is None:
                return None
            progress = study_progress(self._store, self._study_name)
        except Exception as exc:  # shown on the page; the session is not disturbed
            return {"error": _short_error(exc)}
        try:
            found = data_gaps(self._store, self._study_name)
            gaps = {"totals": found.totals(), "gaps": [g.__dict__ for g in found.gaps[:GAPS_SHOWN]],
                    "more": max(0, len(found.gaps) - GAPS_SHOWN)}
        except Exception as exc:  # the progress is still shown
            gaps = {"error": _short_error(exc)}
        people: dict[str, dict[str, Any]] = {}
        conditions: list[str] = []
        for r in progress.rows:
            person = people.setdefault(r.participant, {"code": r.participant, "stratum": r.stratum,
                                                       "status": r.participant_status, "cells": {}, "left": 0})
            person["cells"][r.condition] = [r.done, r.planned]
            person["left"] += r.left
            if r.condition not in conditions:
                conditions.append(r.condition)
        return {"name": progress.study, "conditions": conditions,
                "people": list(people.values())[:STUDY_PEOPLE_SHOWN], "participants": len(people),
                "totals": progress.totals(), "first_condition": progress.first_condition, "data": gaps}

    def _erasures_seen(self, tx: Any, audit_log: Any) -> None:
        """The last erasure that listed this session's id (SQLite reuses an erased session's id): notes before
        it are about the erased session. Erasure rows are read once each."""
        for audit_id, details in tx.execute(select(audit_log.id, audit_log.details)
                                            .where(audit_log.action == "participant.erase",
                                                   audit_log.id > self._erase_scan).order_by(audit_log.id)):
            self._erase_scan = audit_id
            try:
                sessions = json.loads(details).get("sessions") or ()
            except ValueError:
                continue
            if self._session_id in sessions:
                self._erased_until = audit_id

    def _loop(self, now: float) -> dict[str, Any]:
        hub = self.hub
        trial = hub.trial
        tick = hub.tick
        out: dict[str, Any] = {"running": trial is not None, "t": None, "last_tick_ago_s": None,
                               "rate_hz": None, "target_hz": self.rate_hz, "stalled": False,
                               "scans": None, "reports": None, "time_limit_s": None,
                               "samples": None, "samples_behind": None}
        if trial is None:
            self._ticks.clear()
            return out
        counts = self.trial_counts
        out["scans"], out["reports"] = counts.get("scans", 0), counts.get("reports", 0)
        limit = self.progress["step"]["time_limit_s"] if self.progress and self.progress.get("step") else None
        out["time_limit_s"] = limit
        if tick is None:
            return out
        out["t"] = round(float(tick[0]), 2)
        out["last_tick_ago_s"] = round(max(0.0, now - tick[1]), 3)
        out["stalled"] = now - tick[1] > STALL_S
        if len(tick) > 3:
            # one sample per loop tick: those the loop has not taken yet at its rate (a loaded machine, a stall)
            out["samples"] = int(tick[3])
            if self.rate_hz:
                out["samples_behind"] = max(0, int(float(tick[0]) * self.rate_hz) - int(tick[3]))
        if len(tick) > 2:
            with self._lock:
                if not self._ticks or tick[1] - self._ticks[-1][0] >= 0.2:
                    self._ticks.append((tick[1], int(tick[2])))
                first, last = self._ticks[0], self._ticks[-1]
            if last[0] - first[0] > 0.2 and last[1] >= first[1]:
                out["rate_hz"] = round((last[1] - first[1]) / (last[0] - first[0]), 1)
        return out

    def snapshot(self) -> dict[str, Any]:
        """Everything the page shows, as JSON values."""
        self.polls += 1
        with self._lock:
            self._read_store()
            stored = dict(self._stored)
        now = self.clock()
        hub = self.hub
        with hub.lock:
            screen = hub.screen.get("screen")
            prompt = (hub.screen.get("prompt") or {}).get("kind")
            clients = [{"id": c.id[:8], "streams": c.streams, "control": c.id == hub.controller,
                        "agent": c.agent[:80]} for c in hub.clients.values() if c.streams > 0]
        lat = sorted(_copy(hub.latencies_ms)[-2000:])
        phase = dict(self.phase)
        since = phase.pop("since", now)
        timer = None
        if phase.get("kind") == "timer" and phase.get("duration_s"):
            left = float(phase["duration_s"]) - (now - since)
            timer = {"title": phase.get("title"), "purpose": phase.get("purpose"),
                     "duration_s": phase["duration_s"], "left_s": round(max(0.0, left), 1)}
        return {
            "now": datetime.now(UTC).isoformat(timespec="seconds"),
            "session_elapsed_s": round(now - self.started, 1),
            "phase": {**phase, "for_s": round(now - since, 1)},
            "timer": timer,
            "progress": self.progress,
            "loop": self._loop(now),
            "device": {"fault_active": self.fault_active,
                       # dict() copies in one step (the engine thread adds keys meanwhile); a loop over
                       # .items() could see the dict change under it
                       "trial": {k: n for k, n in dict(self.trial_counts).items() if k not in ("scans", "reports")},
                       "session": dict(self.session_counts), "events": _copy(self.events),
                       **((self.progress or {}).get("device") or {})},
            "participant_screen": {"screen": screen, "prompt": prompt, "screens": clients,
                                   "refused_requests": hub.refusals,
                                   "frame_latency_ms_p50": round(lat[len(lat) // 2], 1) if lat else None},
            "lease": stored["lease"],
            "notes": stored["notes"],
            "study": stored.get("study"),
            "store": {"read_at": stored["read_at"], "error": stored["error"]},
        }


__all__ = ["CoordinatorBoard", "progress_of"]
