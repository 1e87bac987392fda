"""Who answers the session's prompts: the interface, virtual answers, and scripted answers from a file.

The engine asks a :class:`SessionUI` for everything that needs a human outside the feedback loop:
showing instructions, running a visible countdown, Likert items, the coordinator's manual outcome
entry and coordinator controls (pause, abort with reason, mark invalid). Three implementations:

* :class:`VirtualUI` – a virtual participant answers (through its plugin's ``answer``), timers run on the
  simulated clock, nothing is shown.
* :class:`ScriptedUI` – answers come from a YAML/JSON file (tests, rehearsals); an invalid scripted answer
  is reported with its reason and the next scripted answer for the same prompt is used, as a person
  would be re-asked.
* :class:`studyctl.engine.terminal.TerminalUI` – rich prompts in a terminal.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from studyctl.engine.clock import Clock
from studyctl.engine.plan import Instrument, Item, ReportSpec, Step
from studyctl.errors import InvalidAnswer, UsageError
from studyctl.inputs import loads_json, read_text
from studyctl.yamlmarks import load_plain


@dataclass(frozen=True)
class Control:
    """A coordinator command: ``pause``, ``abort`` (stop the trial), ``invalid`` (flag it), with a reason, or
    ``note`` (a free-text note on the running trial; the reason is the note)."""

    kind: str
    reason: str = ""


@dataclass(frozen=True)
class TimerResult:
    elapsed_s: float
    ended_early: bool
    paused_s: float = 0.0


@dataclass(frozen=True)
class ManualOutcome:
    """What the coordinator enters for a manual trial (no controller ran): duration and reports."""

    duration_s: float
    reports: tuple[Mapping[str, Any], ...] = ()
    note: str = ""


class SessionUI(Protocol):
    """The prompts of a session. ``interactive`` UIs are shown to a person."""

    interactive: bool

    def message(self, text: str) -> None: ...

    def instructions(self, step: Step, text: str) -> None:
        """Show instructions and return when the participant is ready."""

    def timer(
        self, title: str, duration_s: float, clock: Clock, *, can_end_early: bool, purpose: str
    ) -> TimerResult:
        """Count down ``duration_s`` on ``clock`` (``purpose``: ``break`` or ``familiarisation``)."""

    def ask_item(
        self, instrument: Instrument, item: Item, number: int, context: Mapping[str, Any]
    ) -> tuple[int, float]:
        """One Likert item: returns (code, response time in s)."""

    def manual_outcome(self, step: Step, report: ReportSpec, clock: Clock) -> ManualOutcome:
        """The coordinator times a manual trial and enters the reported locations."""

    def trial_begin(self, step: Step, time_limit_s: float) -> None: ...

    def trial_tick(self, t: float) -> None:
        """Called every loop tick; an interactive UI redraws its countdown a few times a second."""

    def trial_end(self, step: Step, summary: Mapping[str, Any]) -> None: ...

    def poll_control(self) -> Control | None:
        """A pending coordinator command, or None (never blocks)."""

    def wait_unpause(self) -> None:
        """Block until the coordinator resumes a paused session."""

    def close(self) -> None: ...


class _QuietUI:
    """Shared no-op parts of non-interactive UIs."""

    interactive = False
    controls = True  # poll_control/trial_tick must be called every tick

    def __init__(self, log: Callable[[str], None] | None = None) -> None:
        self._log = log

    def message(self, text: str) -> None:
        if self._log is not None:
            self._log(text)

    def instructions(self, step: Step, text: str) -> None:
        return None

    def trial_begin(self, step: Step, time_limit_s: float) -> None:
        return None

    def trial_tick(self, t: float) -> None:
        return None

    def trial_end(self, step: Step, summary: Mapping[str, Any]) -> None:
        return None

    def poll_control(self) -> Control | None:
        return None

    def wait_unpause(self) -> None:
        return None

    def close(self) -> None:
        return None


VIRTUAL_ANSWER_S = 4.0  # simulated seconds a virtual participant takes per questionnaire item


class VirtualUI(_QuietUI):
    """Prompts answered by a virtual participant; breaks elapse on the (simulated) clock.

    ``rng_for(position, index)`` gives the Generator for one answer, so answers depend only on the
    session seed and where in the plan they are asked (resume-safe).
    """

    controls = False  # nobody to press a key: the trial loop need not poll

    def __init__(
        self,
        participant: Any,
        rng_for: Callable[[int, int], np.random.Generator],
        *,
        practise: bool = False,
        clock: Clock | None = None,
        log: Callable[[str], None] | None = None,
    ) -> None:
        super().__init__(log)
        self.clock = clock
        self.participant = participant
        self.rng_for = rng_for
        self.practise = practise
        self._position = 0

    def instructions(self, step: Step, text: str) -> None:
        self._position = step.position

    def timer(self, title, duration_s, clock, *, can_end_early, purpose) -> TimerResult:
        if purpose == "familiarisation" and can_end_early and not self.practise:
            # Virtual participants have nothing to learn from practice: they end it at once.
            return TimerResult(0.0, True)
        start = clock.now()
        clock.sleep_until(start + duration_s)
        return TimerResult(clock.now() - start, False)

    def ask_item(self, instrument, item, number, context) -> tuple[int, float]:
        rng = self.rng_for(int(context.get("position", 0)), number)
        payload = {
            "instrument": instrument.id,
            "version": instrument.version,
            "id": item.id,
            "text": item.text,
            "codes": list(item.codes()),
            "anchors": {p.code: p.label for p in item.scale},
            "reverse": item.reverse,
            **dict(context),
        }
        code = int(self.participant.answer(payload, rng))
        if self.clock is not None:  # reading and answering takes time, also for a virtual participant
            self.clock.sleep_until(self.clock.now() + VIRTUAL_ANSWER_S)
        return code, VIRTUAL_ANSWER_S if self.clock is not None else 0.0

    def manual_outcome(self, step, report, clock) -> ManualOutcome:
        raise UsageError("a virtual participant cannot take a manual condition without a simulated device")


# --------------------------------------------------------------------------------------------------
@dataclass
class Script:
    """Answers for a scripted session (rehearsal or test), loaded from YAML or JSON.

    Keys (all optional)::

        likert:   {ITEM_ID: [code, ...]} or {INSTRUMENT_ID: {ITEM_ID: [code, ...]}}  # consumed in order
        default_likert: 3                      # answer for items without a scripted answer
        outcomes: [{duration_s: 31.5, reports: ["C 3", "A 1"]}, ...]   # manual trials, in order
        trials:   {TRIAL_NUMBER: [{t: 3.0, request: scan}, {t: 9, request: report, answer: "C 3"},
                                  {t: 20, request: finish}]}            # scripted participant
        controls: [{trial: 2, t: 5.0, action: abort, reason: "probe slipped"}]
        familiarisation: end_early | full     # default end_early
    """

    likert: dict[str, Any] = field(default_factory=dict)
    default_likert: int | None = None
    outcomes: list[dict[str, Any]] = field(default_factory=list)
    trials: dict[int, list[dict[str, Any]]] = field(default_factory=dict)
    controls: list[dict[str, Any]] = field(default_factory=list)
    familiarisation: str = "end_early"
    source: str = "<script>"

    @classmethod
    def load(cls, path: str | Path) -> Script:
        p = Path(path)
        if p.is_dir():
            raise UsageError(f"input file {p} is a folder; pass a YAML or JSON answers file to --input")
        if not p.is_file():
            raise UsageError(f"input file {p} does not exist; pass a YAML or JSON answers file to --input")
        text = read_text(p, "answers file (--input)")
        if p.suffix.lower() == ".json":
            try:
                data = loads_json(text)
            except json.JSONDecodeError as exc:
                raise UsageError(f"{p}:{exc.lineno}:{exc.colno}: cannot parse answers file: {exc.msg}") from None
            except ValueError as exc:
                raise UsageError(f"{p}: cannot parse answers file: {exc}") from None
        else:
            try:
                data = load_plain(text, str(p))
            except UsageError as exc:
                raise UsageError(f"cannot parse answers file: {exc}") from None
        return cls.from_mapping(data or {}, source=str(p))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str = "<script>") -> Script:
        allowed = {"likert", "default_likert", "outcomes", "trials", "controls", "familiarisation"}
        if not isinstance(data, Mapping):
            raise UsageError(f"{source}: the answers file must be a mapping with keys {sorted(allowed)}")
        unknown = set(data) - allowed
        if unknown:
            raise UsageError(f"{source}: unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
        fam = data.get("familiarisation", "end_early")
        if fam not in ("end_early", "full"):
            raise UsageError(f"{source}: familiarisation: {fam!r}; allowed: end_early, full")
        trials = {}
        for key, actions in (data.get("trials") or {}).items():
            try:
                trials[int(key)] = list(actions)
            except (TypeError, ValueError):
                raise UsageError(f"{source}: trials: key {key!r} must be a trial number (1, 2, …)") from None
        return cls(
            likert=dict(data.get("likert") or {}),
            default_likert=data.get("default_likert"),
            outcomes=list(data.get("outcomes") or []),
            trials=trials,
            controls=list(data.get("controls") or []),
            familiarisation=fam,
            source=source,
        )


class ScriptedUI(_QuietUI):
    """Prompts answered from a :class:`Script`; invalid answers are logged with the reason and re-asked."""

    def __init__(self, script: Script, *, log: Callable[[str], None] | None = None) -> None:
        super().__init__(log)
        self.script = script
        self._likert_used: dict[tuple[str, str], int] = {}
        self._outcome_index = 0
        self._controls = list(script.controls)
        self._trial_number: int | None = None
        self._trial_t = 0.0
        self.rejected: list[str] = []

    def _reject(self, what: str, exc: InvalidAnswer) -> None:
        msg = f"{what}: {exc}; asking again"
        self.rejected.append(msg)
        self.message(msg)

    def timer(self, title, duration_s, clock, *, can_end_early, purpose) -> TimerResult:
        if purpose == "familiarisation" and can_end_early and self.script.familiarisation == "end_early":
            return TimerResult(0.0, True)
        start = clock.now()
        clock.sleep_until(start + duration_s)
        return TimerResult(clock.now() - start, False)

    def _answers_for(self, instrument: Instrument, item: Item) -> Sequence[Any]:
        block = self.script.likert.get(instrument.id)
        if isinstance(block, Mapping) and item.id in block:
            value = block[item.id]
        else:
            value = self.script.likert.get(item.id)
        if value is None:
            return []
        return value if isinstance(value, list) else [value]

    def ask_item(self, instrument, item, number, context) -> tuple[int, float]:
        answers = self._answers_for(instrument, item)
        key = (instrument.id, item.id)
        while True:
            used = self._likert_used.get(key, 0)
            if used < len(answers):
                raw = answers[used]
                self._likert_used[key] = used + 1
            elif self.script.default_likert is not None:
                raw = self.script.default_likert
            else:
                raise UsageError(
                    f"{self.script.source}: no scripted answer left for item {item.id!r} of {instrument.id!r}; "
                    f"add likert: {{{item.id}: [code, ...]}} or default_likert"
                )
            try:
                return item.parse(str(raw)), 0.0
            except InvalidAnswer as exc:
                self._reject(f"item {item.id}", exc)
                if used >= len(answers):  # the default itself is invalid: asking again would loop
                    raise UsageError(f"{self.script.source}: default_likert {raw!r}: {exc}") from None

    def manual_outcome(self, step, report, clock) -> ManualOutcome:
        if self._outcome_index >= len(self.script.outcomes):
            raise UsageError(
                f"{self.script.source}: no scripted outcome left for manual trial at {step.label()}; "
                "add an entry to outcomes: [{duration_s: …, reports: [...]}]"
            )
        entry = self.script.outcomes[self._outcome_index]
        self._outcome_index += 1
        reports = []
        for raw in entry.get("reports", []):
            try:
                reports.append(report.parse(str(raw)))
            except InvalidAnswer as exc:
                self._reject("report", exc)
        duration = float(entry.get("duration_s", 0.0))
        start = clock.now()
        clock.sleep_until(start + duration)
        return ManualOutcome(duration, tuple(reports), str(entry.get("note", "")))

    def trial_begin(self, step, time_limit_s) -> None:
        self._trial_number = step.trial_index
        self._trial_t = 0.0

    def trial_tick(self, t: float) -> None:
        self._trial_t = t

    def poll_control(self) -> Control | None:
        for i, c in enumerate(self._controls):
            if c.get("trial") == self._trial_number and self._trial_t >= float(c.get("t", 0.0)):
                del self._controls[i]
                return Control(str(c.get("action", "abort")), str(c.get("reason", "scripted")))
        return None
