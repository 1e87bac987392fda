"""The session plan the engine executes: an ordered list of steps plus what they refer to.

A :class:`SessionPlan` is self-contained and JSON-serialisable. It is stored with the session when the
session is created, so a resume needs neither the protocol code nor any random-number replay: the
planned condition order, placements and questionnaires are read back exactly as they were planned.
:func:`studyctl.engine.planning.plan_for_participant` builds one from a protocol and a stored schedule.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal

from studyctl.errors import InvalidAnswer, SessionError
from studyctl.inputs import xy_pair

StepKind = Literal["instructions", "familiarisation", "trial", "break", "questionnaire", "end"]
STEP_KINDS: tuple[str, ...] = ("instructions", "familiarisation", "trial", "break", "questionnaire", "end")
POLICIES: tuple[str, ...] = ("repeat", "invalidate_and_append")
PLAN_VERSION = 1


@dataclass(frozen=True)
class ScalePoint:
    """One point of a rating scale: the stored ``code`` and the anchor ``label`` shown (may be empty)."""

    code: int
    label: str = ""


@dataclass(frozen=True)
class Item:
    """One questionnaire item."""

    id: str
    text: str
    scale: tuple[ScalePoint, ...]
    reverse: bool = False

    def codes(self) -> tuple[int, ...]:
        return tuple(p.code for p in self.scale)

    def parse(self, text: str) -> int:
        """The code for a typed answer, or :class:`InvalidAnswer` naming the allowed codes."""
        raw = text.strip()
        allowed = ", ".join(str(c) for c in self.codes())
        try:
            code = int(raw)
        except ValueError:
            raise InvalidAnswer(f"{raw!r} is not a number; type one of {allowed}") from None
        if code not in self.codes():
            raise InvalidAnswer(f"{code} is not on the scale; type one of {allowed}")
        return code


@dataclass(frozen=True)
class Instrument:
    """A versioned questionnaire: answers are stored as item codes with ``id`` and ``version``."""

    id: str
    version: str
    title: str
    items: tuple[Item, ...]
    instructions: str = ""


@dataclass(frozen=True)
class ReportSpec:
    """What a participant reports during a trial and how a typed report is validated.

    ``kind`` is ``grid`` (seed 000: column and row of the phantom's coordinate map), ``position``
    (seeds 002/003: x and y in millimetres inside ``bounds_mm``) or ``none``.
    """

    kind: str = "none"
    columns: tuple[str, ...] = ()
    rows: tuple[str, ...] = ()
    bounds_mm: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # x_min, x_max, y_min, y_max

    @classmethod
    def from_json(cls, data: Mapping[str, Any] | None) -> ReportSpec:
        """Inverse of ``dataclasses.asdict`` (missing keys take the defaults; ``None`` is no report)."""
        rep = dict(data or {})
        x0, x1, y0, y1 = (float(b) for b in rep.get("bounds_mm", (0, 0, 0, 0)))
        return cls(
            kind=rep.get("kind", "none"),
            columns=tuple(str(c) for c in rep.get("columns", ())),
            rows=tuple(str(r) for r in rep.get("rows", ())),
            bounds_mm=(x0, x1, y0, y1),
        )

    def describe(self) -> str:
        if self.kind == "grid":
            return (
                f"column ({self.columns[0]}–{self.columns[-1]}) and row ({self.rows[0]}–{self.rows[-1]}), "
                f"e.g. '{self.columns[0]} {self.rows[0]}'"
            )
        if self.kind == "position":
            x0, x1, y0, y1 = self.bounds_mm
            return f"x and y in mm (x {x0:g}–{x1:g}, y {y0:g}–{y1:g}), e.g. '{(x0 + x1) / 2:g} {(y0 + y1) / 2:g}'"
        return "nothing (this study takes no location reports)"

    def parse(self, text: str) -> dict[str, Any]:
        """Validate a typed report; returns the payload stored with the report event."""
        raw = text.strip()
        if self.kind == "grid":
            tokens = [t for t in re.split(r"[\s,;:/]+", raw) if t]
            if len(tokens) == 1:  # "C3" style
                m = re.fullmatch(r"([A-Za-z]+)(\d+)", tokens[0])
                tokens = [m.group(1), m.group(2)] if m else tokens
            if len(tokens) != 2:
                raise InvalidAnswer(f"{raw!r}: give a {self.describe()}")
            col, row = tokens
            cols = {c.upper(): c for c in self.columns}
            if col.upper() not in cols:
                raise InvalidAnswer(f"column {col!r} is not on the grid; columns are {', '.join(self.columns)}")
            if row not in self.rows:
                raise InvalidAnswer(f"row {row!r} is not on the grid; rows are {', '.join(self.rows)}")
            return {"column": cols[col.upper()], "row": row}
        if self.kind == "position":
            tokens = [t for t in re.split(r"[\s,;]+", raw) if t]
            x, y = xy_pair(tokens, wrong_count=f"{raw!r}: give {self.describe()}",
                           not_numbers=f"{raw!r}: x and y must be numbers in mm", error=InvalidAnswer)
            x0, x1, y0, y1 = self.bounds_mm
            if not (math.isfinite(x) and math.isfinite(y) and x0 <= x <= x1 and y0 <= y <= y1):
                raise InvalidAnswer(f"({x:g}, {y:g}) mm is outside the tissue (x {x0:g}–{x1:g}, y {y0:g}–{y1:g})")
            return {"x_mm": x, "y_mm": y}
        raise InvalidAnswer("this study takes no location reports")

    def validate_payload(self, payload: Mapping[str, Any]) -> dict[str, Any]:
        """Validate a report that arrives as a payload (virtual participants, scripts)."""
        if self.kind == "grid":
            return self.parse(f"{payload.get('column')} {payload.get('row')}")
        if self.kind == "position":
            return self.parse(f"{payload.get('x_mm')} {payload.get('y_mm')}")
        return self.parse("")


@dataclass(frozen=True)
class ConditionSpec:
    """How to run one condition: plugins by entry-point name and their parameters.

    ``controller`` is None for manual conditions (no controller runs; a person's outcome is entered by the
    coordinator, a virtual participant palpates the scene directly). ``visual`` is ``none``,
    ``on_request`` (scans counted) or ``realtime`` (view updates continuously, nothing counted).
    """

    id: str
    label: str = ""
    controller: str | None = None
    params: Mapping[str, Any] = field(default_factory=dict)
    visual: str = "none"
    manual: bool = False
    rate_hz: float | None = None  # None → the controller's rate, else 50 Hz
    view_label: str = ""  # the participant view's neutral name for it ("" → only "Trial N")


@dataclass(frozen=True)
class Step:
    """One step of a session. ``position`` is the step's stable 1-based identifier; list order is run order."""

    position: int
    kind: str
    condition: str | None = None
    block: int | None = None
    repetition: int | None = None
    trial_index: int | None = None  # 1-based planned trial number (trials only)
    duration_s: float | None = None  # time limit, familiarisation maximum or break length
    data: Mapping[str, Any] = field(default_factory=dict)  # placement, instrument id, text …
    replaces: int | None = None  # position of the trial this replacement stands in for

    def label(self) -> str:
        parts = [f"step {self.position}", self.kind]
        if self.condition:
            parts.append(self.condition)
        if self.kind == "trial" and self.repetition is not None:
            parts.append(f"rep {self.repetition}")
        return " ".join(parts)


@dataclass(frozen=True)
class SessionPlan:
    """Everything a session needs, stored as JSON with the session."""

    steps: tuple[Step, ...]
    conditions: Mapping[str, ConditionSpec]
    instruments: Mapping[str, Instrument] = field(default_factory=dict)
    report: ReportSpec = field(default_factory=ReportSpec)
    scene: str | None = None
    scene_spec: Mapping[str, Any] = field(default_factory=dict)
    hardware_device: Mapping[str, Any] | None = None  # {"plugin": name, "params": {...}} for people
    simulated_device: Mapping[str, Any] | None = None  # virtual participants and rehearsals without hardware
    virtual_participant: Mapping[str, Any] | None = None  # {"plugin": name, "params": {...}}
    requests: tuple[str, ...] = ("report", "finish")
    interrupted_trial: str = "repeat"
    checkpoint: str = "trial"  # "condition": a resume re-runs the condition's instructions and practice
    study: str = ""
    version: int = PLAN_VERSION

    def __post_init__(self) -> None:
        if self.interrupted_trial not in POLICIES:
            raise SessionError(
                f"interrupted-trial policy {self.interrupted_trial!r} is unknown; allowed: {', '.join(POLICIES)}"
            )
        seen: set[int] = set()
        for step in self.steps:
            if step.kind not in STEP_KINDS:
                raise SessionError(f"plan step {step.position}: kind {step.kind!r} unknown; allowed: {STEP_KINDS}")
            if step.position in seen:
                raise SessionError(f"plan step position {step.position} appears twice")
            seen.add(step.position)
            if step.kind == "trial" and step.condition not in self.conditions:
                raise SessionError(f"plan step {step.position}: condition {step.condition!r} is not defined")
            if step.kind == "questionnaire" and step.data.get("instrument") not in self.instruments:
                raise SessionError(
                    f"plan step {step.position}: instrument {step.data.get('instrument')!r} is not defined"
                )

    # -- lookups -----------------------------------------------------------------------------------
    def step(self, position: int) -> Step:
        for s in self.steps:
            if s.position == position:
                return s
        raise SessionError(f"the plan has no step {position}")

    def trials(self) -> list[Step]:
        return [s for s in self.steps if s.kind == "trial"]

    def with_condition_rates(self, rates: Mapping[str, float]) -> SessionPlan:
        """This plan with the loop rate of the named conditions fixed (a simulated session at a reduced rate);
        being part of the stored plan, the rates also hold when the session is resumed."""
        unknown = sorted(set(rates) - set(self.conditions))
        if unknown:
            raise SessionError(f"loop rates for unknown conditions: {', '.join(unknown)}")
        conditions = {
            k: replace(c, rate_hz=float(rates[k])) if k in rates else c for k, c in self.conditions.items()
        }
        return replace(self, conditions=conditions)

    def with_replacement(self, position: int) -> tuple[SessionPlan, Step]:
        """A plan with a replacement for trial ``position`` appended after the last trial of its block."""
        original = self.step(position)
        if original.kind != "trial":
            raise SessionError(f"step {position} is a {original.kind}, only trials are replaced")
        new_pos = max(s.position for s in self.steps) + 1
        new = replace(original, position=new_pos, replaces=original.replaces or original.position)
        steps = list(self.steps)
        last = max(i for i, s in enumerate(steps) if s.kind == "trial" and s.block == original.block)
        steps.insert(last + 1, new)
        return replace(self, steps=tuple(steps)), new

    # -- JSON ------------------------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        return {
            "version": self.version,
            "study": self.study,
            "interrupted_trial": self.interrupted_trial,
            "scene": self.scene,
            "scene_spec": _plain(self.scene_spec),
            "hardware_device": _plain(self.hardware_device),
            "simulated_device": _plain(self.simulated_device),
            "virtual_participant": _plain(self.virtual_participant),
            "requests": list(self.requests),
            "checkpoint": self.checkpoint,
            "report": _plain(asdict(self.report)),
            "conditions": {k: _condition_json(v) for k, v in self.conditions.items()},
            "instruments": {k: _plain(asdict(v)) for k, v in self.instruments.items()},
            "steps": [_plain(asdict(s)) for s in self.steps],
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SessionPlan:
        if data.get("version") != PLAN_VERSION:
            raise SessionError(
                f"stored plan version {data.get('version')!r} is not supported by this studyctl "
                f"(expects {PLAN_VERSION}); upgrade studyctl"
            )
        report = ReportSpec.from_json(data.get("report"))
        conditions = {k: ConditionSpec(**v) for k, v in data["conditions"].items()}
        instruments = {
            k: Instrument(
                id=v["id"],
                version=str(v["version"]),
                title=v.get("title", ""),
                instructions=v.get("instructions", ""),
                items=tuple(
                    Item(
                        id=i["id"],
                        text=i["text"],
                        reverse=bool(i.get("reverse", False)),
                        scale=tuple(ScalePoint(int(p["code"]), p.get("label", "")) for p in i["scale"]),
                    )
                    for i in v["items"]
                ),
            )
            for k, v in data.get("instruments", {}).items()
        }
        steps = tuple(Step(**s) for s in data["steps"])
        return cls(
            steps=steps,
            conditions=conditions,
            instruments=instruments,
            report=report,
            scene=data.get("scene"),
            scene_spec=data.get("scene_spec") or {},
            hardware_device=data.get("hardware_device"),
            simulated_device=data.get("simulated_device"),
            virtual_participant=data.get("virtual_participant"),
            requests=tuple(data.get("requests", ("report", "finish"))),
            checkpoint=data.get("checkpoint", "trial"),
            interrupted_trial=data.get("interrupted_trial", "repeat"),
            study=data.get("study", ""),
        )


def _plain(value: Any) -> Any:
    """Tuples → lists, mappings → dicts, numpy scalars → Python, so the plan round-trips through JSON."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "item") and callable(value.item):
        return value.item()
    return value


def likert(
    codes: Sequence[int], anchors: Mapping[int, str] | None = None
) -> tuple[ScalePoint, ...]:
    """Scale points for a Likert item: ``likert(range(1, 6), {1: "strongly disagree", 5: "strongly agree"})``."""
    anchors = anchors or {}
    return tuple(ScalePoint(int(c), anchors.get(int(c), "")) for c in codes)


def _condition_json(spec: ConditionSpec) -> dict[str, Any]:
    # A blank view label is left out: plans stored before it existed keep their exact JSON.
    out = _plain(asdict(spec))
    if not out.get("view_label"):
        out.pop("view_label", None)
    return out
