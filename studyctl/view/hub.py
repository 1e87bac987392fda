"""The state shared by the session engine and the participant view's server threads.

Three parties touch it, with different rules:

* the **1 kHz trial loop** (through :class:`~studyctl.view.frontend.ViewParticipant` and
  ``ViewUI.trial_tick``) only *replaces references* — the latest frame state and the latest trial time —
  and pops requests from a deque. No lock, no allocation beyond one small tuple, no I/O: a reference
  assignment is atomic in CPython, so a reader sees either the old or the new state, never a torn one;
* the **engine thread between trials** (``ViewUI``) sets the screen (instructions, a Likert item, the trial
  screen …) under :attr:`ViewHub.lock`, and drains the view's log into the recorder;
* the **server threads** read all of it, encode frames (once per frame, shared by all browsers), take the
  participant's inputs and queue log events for the engine thread to write.
"""

from __future__ import annotations

import collections
import itertools
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from studyctl.engine.plan import ReportSpec
from studyctl.errors import InvalidAnswer
from studyctl.plugins.interfaces import Request
from studyctl.view import encode

log = logging.getLogger("studyctl.view")

FRAME_HZ = 60.0
# A control screen that disconnects keeps control this long (a reload comes back within it).
CONTROL_GRACE_S = 10.0
# At most this many refusals are written to the session's events (the count goes on; the log says so).
MAX_LOGGED_REFUSALS = 200
# Frames whose draw time we can still attribute (a browser acknowledges within a fraction of a second).
SENT_MEMORY = 1024


# Screen fields kept off the participant's page (logged only): the condition would unblind the participant.
PRIVATE_FIELDS = ("condition",)

class FrameState(NamedTuple):
    """What the trial loop dropped into the slot: the scene's frame and when its state was taken.

    ``t`` is the trial time of the tick that produced the state, ``ts`` a ``time.perf_counter()`` reading
    taken no later than the state (so latencies measured from it are upper bounds), ``source`` is
    ``scan`` (a counted CT scan) or ``view`` (a real-time frame).
    """

    seq: int
    t: float
    ts: float
    source: str
    frame: Any
    count: int = 0  # scans so far in this trial (source "scan")


@dataclass
class Client:
    """One browser tab (its id lives in the tab's sessionStorage, so a reload keeps it)."""

    id: str
    agent: str
    first_seen: float
    streams: int = 0
    last_seen: float = 0.0


@dataclass
class Prompt:
    """Something the participant answers in the view: ``ready`` (instructions), ``start`` (a trial) or
    ``likert`` (an item; ``codes`` are the allowed answers)."""

    id: int
    kind: str
    codes: tuple[int, ...] = ()
    answer: str | None = None
    taken: bool = False
    client: str | None = None
    page_rt_s: float | None = None


@dataclass
class TrialView:
    """What the view needs to know about the running trial."""

    visual: str
    requests: tuple[str, ...]
    report: ReportSpec
    time_limit_s: float
    scans: int = 0
    reports: int = 0
    log: list[dict[str, Any]] = field(default_factory=list)  # frames drawn, filled by server threads


class ViewHub:
    """Shared state of one participant view (see the module docstring for who may touch what)."""

    def __init__(self, *, clock: Callable[[], float] = time.perf_counter) -> None:
        self.clock = clock
        self.lock = threading.Lock()
        self.closed = False
        # -- written by the trial loop only (reference swaps) --------------------------------------
        self.latest: FrameState | None = None
        # (trial time, perf_counter, ticks so far, ticks of this trial) of the last loop tick
        self.tick: tuple[float, ...] | None = None
        self.inbox: collections.deque[Request] = collections.deque()
        # -- screen (engine thread, under lock) -------------------------------------------------------
        self.screen: dict[str, Any] = {"screen": "waiting"}
        self.screen_version = 1
        self.prompt: Prompt | None = None
        self.trial: TrialView | None = None
        self.answerable = False  # a prompt can be answered in the view (a terminal takes the answer)
        self._prompt_ids = itertools.count(1)
        self._screen_shown: dict[int, float] = {}
        self._screen_summary: dict[int, dict[str, Any]] = {}
        # -- clients (server threads, under lock) -----------------------------------------------------
        self.clients: dict[str, Client] = {}
        self.controller: str | None = None
        self._controller_lost: float | None = None
        # -- encoding (server threads, under _enc_lock) ---------------------------------------------
        self._enc_lock = threading.Lock()
        self._enc_seq = -1
        self._enc: tuple[dict[str, Any], dict[str, Any] | None] | None = None
        self.codec = encode.GreyCodec()
        self._surface_obj: Any = None
        self.surface_id = 0
        self.surface_msg: dict[str, Any] | None = None
        self._sent: collections.OrderedDict[int, FrameState] = collections.OrderedDict()
        # -- log for the engine thread --------------------------------------------------------------
        self.pending_log: collections.deque[tuple[str, dict[str, Any]]] = collections.deque()
        self.refusals = 0
        self.latencies_ms: collections.deque[float] = collections.deque(maxlen=100_000)
        self.sync_rtt_ms: dict[str, float] = {}  # best clock-sync round trip of each page (error ≤ half)

    # ================================================================ trial loop (lock-free)
    def put_frame(self, state: FrameState) -> None:
        self.latest = state

    # ================================================================ engine thread: screens
    def show(self, screen: str, *, prompt: str | None = None, codes: tuple[int, ...] = (), **fields: Any) -> int | None:
        """Replace what the participant sees; returns the new prompt's id when ``prompt`` is given."""
        # Blinding: the condition goes to the session's log (what was shown when), never onto the page.
        private = {k: fields.pop(k) for k in PRIVATE_FIELDS if k in fields}
        with self.lock:
            self.prompt = Prompt(next(self._prompt_ids), prompt, tuple(codes)) if prompt else None
            body: dict[str, Any] = {"screen": screen, **fields}
            if self.prompt is not None:
                body["prompt"] = {"id": self.prompt.id, "kind": self.prompt.kind, "answerable": self.answerable}
            self.screen = body
            self.screen_version += 1
            self._screen_summary[self.screen_version] = {
                k: body[k] for k in ("screen", "item", "instrument", "trial") if k in body
            } | private | ({"prompt": prompt} if prompt else {})
            return self.prompt.id if self.prompt else None

    def update(self, **fields: Any) -> None:
        """Change fields of the current screen (keeps its prompt)."""
        fields = {k: v for k, v in fields.items() if k not in PRIVATE_FIELDS}
        with self.lock:
            self.screen = {**self.screen, **fields}
            self.screen_version += 1

    def clear_prompt(self) -> None:
        with self.lock:
            if self.prompt is not None:
                self.prompt = None
                self.screen = {k: v for k, v in self.screen.items() if k != "prompt"}
                self.screen_version += 1

    def take_answer(self) -> str | None:
        """The view's answer to the current prompt, once (the terminal's answer source polls this)."""
        p = self.prompt
        if p is None or p.answer is None or p.taken:
            return None
        with self.lock:
            if self.prompt is not p or p.taken:
                return None
            p.taken = True
            return p.answer

    def begin_trial(self, trial: TrialView) -> None:
        with self._enc_lock:
            self.codec = encode.GreyCodec()
            self._surface_obj = None
            self.surface_msg = None
            self._enc = None
        self.latest = None
        self.tick = None
        self.inbox.clear()  # a click before the trial started must not count in it
        self.trial = trial

    def end_trial(self) -> TrialView | None:
        trial, self.trial = self.trial, None
        self.inbox.clear()
        return trial

    # ================================================================ server threads: clients
    def connect(self, client_id: str, agent: str) -> str:
        now = self.clock()
        with self.lock:
            c = self.clients.get(client_id)
            fresh = c is None
            if c is None:
                c = self.clients[client_id] = Client(client_id, agent[:200], now)
            c.streams += 1
            c.last_seen = now
            self._maintain(now)
            if self.controller is None:
                self.controller = client_id
            if self.controller == client_id:
                self._controller_lost = None
            role = self.role(client_id)
        self.note("view_client", {"action": "connected" if fresh else "reconnected", "client": client_id,
                                  "role": role, "agent": agent[:200]})
        return role

    def disconnect(self, client_id: str) -> None:
        now = self.clock()
        with self.lock:
            c = self.clients.get(client_id)
            if c is None:
                return
            c.streams = max(0, c.streams - 1)
            c.last_seen = now
            if c.streams == 0 and self.controller == client_id:
                self._controller_lost = now
        self.note("view_client", {"action": "disconnected", "client": client_id})

    def role(self, client_id: str) -> str:
        return "control" if self.controller == client_id else "read_only"

    def maintain(self) -> None:
        with self.lock:
            self._maintain(self.clock())

    def _maintain(self, now: float) -> None:
        """Hand control on when its screen has been gone for longer than a reload takes."""
        if self.controller is None or self._controller_lost is None:
            return
        if now - self._controller_lost < CONTROL_GRACE_S:
            return
        old = self.controller
        waiting = sorted((c for c in self.clients.values() if c.streams > 0 and c.id != old),
                         key=lambda c: c.first_seen)
        self.controller = waiting[0].id if waiting else None
        self._controller_lost = None
        self.note("view_client", {"action": "control_released", "client": old, "to": self.controller})

    # ================================================================ server threads: participant input
    def submit(self, client_id: str, body: Mapping[str, Any]) -> tuple[int, dict[str, Any]]:
        """Take one input from a browser; returns (HTTP status, JSON reply). Every input is logged."""
        kind = str(body.get("kind", ""))
        with self.lock:
            self._maintain(self.clock())
            role = self.role(client_id) if client_id in self.clients else "unknown"
        if role != "control":
            reason = "this screen is read-only: another screen controls the session" if role == "read_only" \
                else "unknown screen: reload the page"
            self.note("view_input", {"kind": kind, "client": client_id, "accepted": False, "reason": reason})
            return 403, {"ok": False, "error": reason}
        if kind in ("ready", "start", "likert"):
            status, reply = self._answer(client_id, kind, body)
        elif kind in ("scan", "report", "finish"):
            status, reply = self._request(kind, body)
        else:
            status, reply = 400, {"ok": False, "error": f"unknown input {kind!r}"}
        detail = {"kind": kind, "client": client_id, "accepted": status == 200}
        if status != 200:
            detail["reason"] = reply.get("error", "")
        for key in ("prompt", "code", "text"):
            if key in body:
                detail[key] = body[key]
        self.note("view_input", detail)
        return status, reply

    def _answer(self, client_id: str, kind: str, body: Mapping[str, Any]) -> tuple[int, dict[str, Any]]:
        with self.lock:
            p = self.prompt
            if p is None or p.id != body.get("prompt") or p.kind != kind:
                return 409, {"ok": False, "error": "this question is no longer asked"}
            if not self.answerable:
                return 409, {"ok": False, "error": "the coordinator answers this one at the terminal"}
            if p.answer is not None:
                return 409, {"ok": False, "error": "already answered"}
            if kind == "likert":
                code = body.get("code")
                if isinstance(code, bool) or not isinstance(code, int) or code not in p.codes:
                    return 400, {"ok": False, "error": f"{code!r} is not on the scale; allowed: {list(p.codes)}"}
                p.answer = str(code)
            else:
                p.answer = ""
            p.client = client_id
            rt = body.get("rt_s")
            p.page_rt_s = float(rt) if isinstance(rt, (int, float)) and math.isfinite(rt) else None
        return 200, {"ok": True}

    def _request(self, kind: str, body: Mapping[str, Any]) -> tuple[int, dict[str, Any]]:
        trial = self.trial
        if trial is None or self.screen.get("screen") != "trial":
            return 409, {"ok": False, "error": "no trial is running"}
        if kind not in trial.requests:
            return 409, {"ok": False, "error": f"{kind} is not part of this study"}
        if kind == "scan":
            if trial.visual == "realtime":
                return 409, {"ok": False, "error": "the view updates continuously: no scan needed"}
            if trial.visual != "on_request":
                return 409, {"ok": False, "error": "this condition shows no images"}
            self.inbox.append(Request("scan"))
            return 200, {"ok": True}
        if kind == "report":
            text = str(body.get("text", ""))
            try:
                payload = trial.report.parse(text)  # the terminal's own check of a typed report
            except InvalidAnswer as exc:
                return 400, {"ok": False, "error": f"report not accepted: {exc}"}
            trial.reports += 1
            self.inbox.append(Request("report", payload))
            return 200, {"ok": True, "report": payload}
        self.inbox.append(Request("finish"))
        return 200, {"ok": True}

    # ================================================================ server threads: frames
    def encoded(self, state: FrameState) -> tuple[dict[str, Any], dict[str, Any] | None]:
        """(frame message, new key-image message or None) for ``state``; computed once, shared."""
        with self._enc_lock:
            if self._enc_seq == state.seq and self._enc is not None:
                return self._enc
            frame = state.frame
            kind = encode.frame_kind(frame)
            key = None
            if kind == "ct":
                key, msg = encode.ct_message(frame, self.codec)
            elif kind == "tissue":
                surface = frame["surface"]
                if surface is not self._surface_obj:
                    self._surface_obj = surface
                    self.surface_id += 1
                    self.surface_msg = {"surface": self.surface_id, **encode.surface_message(surface)}
                msg = {**encode.tissue_message(frame), "surface": self.surface_id}
            else:
                msg = encode.generic_message(frame)
            msg.update({"seq": state.seq, "t": state.t, "ts": state.ts, "source": state.source})
            if state.source == "scan":
                msg["scan"] = state.count
            self._sent[state.seq] = state
            while len(self._sent) > SENT_MEMORY:
                self._sent.popitem(last=False)
            self._enc_seq, self._enc = state.seq, (msg, key)
            return self._enc

    def acknowledge(self, client_id: str, frames: list, screens: list) -> int:
        """Record when a browser drew frames / screens (times already converted to our clock)."""
        n = 0
        trial = self.trial
        for seq, drawn in _stamps(frames[:600]):
            with self._enc_lock:
                state = self._sent.get(seq)
            if state is None or not math.isfinite(drawn):
                continue
            latency = (drawn - state.ts) * 1000.0
            if client_id == self.controller:
                self.latencies_ms.append(latency)
            if trial is not None:
                trial.log.append({"seq": seq, "source": state.source, "state_t": state.t,
                                  "drawn_t": state.t + (drawn - state.ts), "latency_ms": latency,
                                  "client": client_id})
            n += 1
        for version, drawn in _stamps(screens[:50]):
            with self.lock:
                summary = self._screen_summary.get(version)
                if summary is None or version in self._screen_shown:
                    continue  # not a screen change of ours, or already logged
                self._screen_shown[version] = drawn
            self.note("view_shown", {**summary, "version": version, "client": client_id, "drawn_perf": drawn})
        return n

    # ================================================================ log
    def note(self, kind: str, payload: dict[str, Any]) -> None:
        """Queue an event for the session record (written by the engine thread at its next safe point)."""
        self.pending_log.append((kind, {**payload, "wall": time.time()}))

    def refuse(self, reason: str, detail: dict[str, Any]) -> None:
        self.refusals += 1
        log.warning("participant view refused a request: %s %s", reason, detail)
        if self.refusals <= MAX_LOGGED_REFUSALS:
            self.note("view_refused", {"reason": reason, **detail, "count": self.refusals})

    def drain_log(self) -> list[tuple[str, dict[str, Any]]]:
        out = []
        while self.pending_log:
            out.append(self.pending_log.popleft())
        return out


def _stamps(items: list) -> Iterator[tuple[int, float]]:
    """The well-formed ``[id, time]`` pairs a browser sent (anything else is skipped)."""
    for item in items:
        try:
            yield int(item[0]), float(item[1])
        except (TypeError, ValueError, IndexError):
            continue
