"""Participants who are people: at the terminal (:class:`TerminalParticipant`) or scripted from a file.

A person's hand acts on the hardware, which the device reads by itself; what a person adds to each loop
tick are requests (scan, report, finish) typed at the terminal. Neither class ever blocks the loop.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from studyctl.engine.plan import ReportSpec
from studyctl.errors import InvalidAnswer, SessionError
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo


def report_spec(info: TrialInfo) -> ReportSpec:
    """The report rules the engine put in ``info.public['report']``."""
    return ReportSpec.from_json(info.public.get("report"))


class TerminalParticipant(Participant):
    """A person at the terminal: keys s (scan), r (report, then type it), f (finished).

    The engine attaches the shared :class:`~studyctl.engine.terminal.Terminal` and its UI with
    :meth:`attach` before the first trial.
    """

    name: ClassVar[str] = "person"
    virtual: ClassVar[bool] = False
    practises: ClassVar[bool] = True  # familiarisation runs the condition's feedback live for this person

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        self.params = dict(params or {})
        self.term = None
        self.ui = None
        self._info: TrialInfo | None = None
        self._spec = ReportSpec()

    def attach(self, term, ui) -> None:
        self.term = term
        self.ui = ui

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        if self.term is None:
            raise SessionError("TerminalParticipant.attach(terminal, ui) must be called before a trial")
        self._info = info
        self._spec = report_spec(info)

    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        term = self.term
        term.pump()
        requests: list[Request] = []
        allowed = set(self._info.public.get("requests", ("report", "finish"))) if self._info else set()
        key = term.take_key("sf")
        if key == "s":
            if "scan" not in allowed:
                term.notice = "scans are not part of this study"
            elif self._info.visual == "realtime":
                term.notice = "the view updates continuously: no scan needed (not counted)"
            else:
                requests.append(Request("scan"))
                self.ui.scans += 1
                term.notice = f"scan {self.ui.scans} shown"
        elif key == "f":
            requests.append(Request("finish"))
        text = term.take_line("report")
        if text is not None:
            try:
                payload = self._spec.parse(text)
            except InvalidAnswer as exc:
                term.notice = f"report not accepted: {exc}; press r and type it again"
            else:
                requests.append(Request("report", payload))
                self.ui.reports += 1
                term.notice = f"reported {text}"
        return Action({}, tuple(requests))


class ScriptedParticipant(Participant):
    """A rehearsal participant whose requests come from a script (``trials:`` in the answers file).

    Each entry ``{t: seconds, request: scan|report|finish, answer: "3 4"}`` fires once when the trial time
    reaches ``t``. A report whose answer is invalid is logged with the reason and skipped, as a person
    would be asked again.
    """

    name: ClassVar[str] = "scripted_person"
    virtual: ClassVar[bool] = False

    def __init__(self, script, log=None) -> None:
        self.script = script
        self.log = log
        self.rejected: list[str] = []
        self._queue: list[dict[str, Any]] = []
        self._spec = ReportSpec()

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        number = info.public.get("trial_index")
        self._queue = sorted((dict(a) for a in self.script.trials.get(number, [])), key=lambda a: float(a["t"]))
        self._spec = report_spec(info)

    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        requests: list[Request] = []
        while self._queue and float(self._queue[0]["t"]) <= t + 1e-9:
            entry = self._queue.pop(0)
            kind = str(entry.get("request", ""))
            if kind == "report":
                try:
                    requests.append(Request("report", self._spec.parse(str(entry.get("answer", "")))))
                except InvalidAnswer as exc:
                    msg = f"report {entry.get('answer')!r} at t={entry['t']}: {exc}; asking again"
                    self.rejected.append(msg)
                    if self.log is not None:
                        self.log(msg)
            elif kind in ("scan", "finish"):
                requests.append(Request(kind))
        return Action({}, tuple(requests))
