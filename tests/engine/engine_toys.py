"""Minimal scripted plugins implementing the engine's interfaces (independent of the real plugins)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from studyctl.engine.plan import (
    ConditionSpec,
    Instrument,
    Item,
    ReportSpec,
    SessionPlan,
    Step,
    likert,
)
from studyctl.errors import DeviceError
from studyctl.plugins.interfaces import (
    Action,
    ChannelLimit,
    Controller,
    Device,
    DeviceLimits,
    Observation,
    Participant,
    Request,
    Scene,
    TrialInfo,
)


class ToyScene(Scene):
    """Tumours at grid cells; the sensor reads more force above a tumour."""

    name = "toy_scene"

    def __init__(self, sites: list[tuple[int, int]]) -> None:
        self.sites = sites

    @classmethod
    def build(cls, spec, placement, needs, rng):
        return cls([tuple(s) for s in placement.get("sites", [])])

    def sense(self, inputs):
        x, y, z = inputs.get("x", 0.0), inputs.get("y", 0.0), inputs.get("z_mm", 0.0)
        stiff = 2.0 if (round(x), round(y)) in self.sites else 1.0
        return {"force_n": stiff * max(z, 0.0) * 0.1}

    def view(self, inputs):
        return {"x": inputs.get("x", 0.0), "y": inputs.get("y", 0.0)}

    def truth(self):
        return {"sites": self.sites}


class ToyDevice(Device):
    name = "toy_device"
    limits = DeviceLimits(outputs=(ChannelLimit("balloon_pct", 0.0, 100.0, safe=0.0),))
    disconnect_at: float | None = None  # set by tests
    instances: list[ToyDevice] = []

    def __init__(self, scene=None, rng=None, params=None) -> None:
        self.scene = scene
        self.inputs: dict[str, float] = {}
        self.written: list[dict[str, float]] = []
        self.opened = False
        self.closed = 0
        ToyDevice.instances.append(self)

    def open(self):
        self.opened = True

    def apply_input(self, inputs):
        self.inputs = dict(inputs)

    def read(self, t):
        if self.disconnect_at is not None and t >= self.disconnect_at:
            raise DeviceError("toy device: USB link lost")
        return Observation(t, self.scene.sense(self.inputs) if self.scene else {})

    def write(self, command):
        self.written.append(dict(command))

    def feedback(self):
        return dict(self.written[-1]) if self.written else {}

    def close(self):
        self.written.append(self.limits.safe_command())
        self.closed += 1


class ToyController(Controller):
    name = "toy_linear"
    rate_hz = 50.0

    def reset(self):
        pass

    def step(self, obs):
        return {"balloon_pct": 40.0 * obs.values.get("force_n", 0.0)}


class ToyParticipant(Participant):
    """Visits grid cells in a seeded order, scans sometimes, reports cells that felt stiff, then finishes."""

    name = "toy_participant"
    virtual = True
    crash_at: tuple[int, float] | None = None  # (trial_index, t): raise Crash there
    interrupt_at: tuple[int, float] | None = None

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        self.info = info
        self.rng = rng
        self.cells = [(int(c), int(r)) for c in range(1, 4) for r in range(1, 4)]
        rng.shuffle(self.cells)
        self.dwell = float(rng.uniform(0.5, 1.5))
        self.finish_t = float(rng.uniform(4.0, 9.0))
        self.reported: set[tuple[int, int]] = set()
        self.peak = 0.0

    def act(self, t, percept):
        idx = self.info.public.get("trial_index")
        if self.crash_at is not None and self.crash_at == (idx, round(t, 2)):
            raise Crash()
        if self.interrupt_at is not None and self.interrupt_at == (idx, round(t, 2)):
            raise KeyboardInterrupt()
        k = min(int(t / self.dwell), len(self.cells) - 1)
        cell = self.cells[k]
        felt = float(percept.get("balloon_pct", 0.0))
        requests = []
        if felt > 6.0 and cell not in self.reported:
            self.reported.add(cell)
            requests.append(Request("report", {"column": str(cell[0]), "row": str(cell[1])}))
        if self.info.visual == "on_request" and abs(t - 2.0) < 1e-9:
            requests.append(Request("scan"))
        if t >= self.finish_t:
            requests.append(Request("finish"))
        z = 10.0 * (1 - abs(((t / self.dwell) % 1.0) * 2 - 1))
        return Action({"x": cell[0], "y": cell[1], "z_mm": z}, tuple(requests))

    def answer(self, item, rng):
        codes = item["codes"]
        return int(codes[int(rng.integers(0, len(codes)))])


class Crash(BaseException):
    """Stands in for the process dying: nothing catches it, nothing gets recorded."""


PLUGINS = {
    "scene": {"toy_scene": ToyScene},
    "device": {"toy_device": ToyDevice},
    "controller": {"toy_linear": ToyController},
    "participant": {"toy_participant": ToyParticipant},
}


def toy_plan(policy: str = "repeat", *, time_limit: float = 12.0, checkpoint: str = "trial") -> SessionPlan:
    instrument = Instrument(
        id="ease", version="1.0", title="Ease",
        items=(
            Item("q1", "The task was easy.", likert(range(1, 6), {1: "strongly disagree", 5: "strongly agree"})),
            Item("q2", "I felt the tumours.", likert(range(1, 6), {1: "strongly disagree", 5: "strongly agree"})),
            Item("q3", "I would use it again.", likert(range(1, 6), {1: "strongly disagree", 5: "strongly agree"})),
        ),
    )
    final = Instrument(id="final", version="2", title="End", items=(
        Item("pref", "Feedback helped.", likert(range(1, 6))),
    ))
    conds = {
        "A": ConditionSpec("A", "linear", controller="toy_linear", visual="on_request"),
        "B": ConditionSpec("B", "none", controller=None, visual="none"),
    }
    steps: list[Step] = [Step(1, "instructions", data={"text": "Find the tumours."})]
    pos = 2
    trial_index = 1
    placements = [[(1, 1), (2, 3)], [(3, 2), (1, 3)], [(2, 2), (3, 3)], [(1, 2), (3, 1)]]
    for block, cond in enumerate(["A", "B"], start=1):
        steps.append(Step(pos, "familiarisation", cond, block, duration_s=300.0, data={"can_end_early": True}))
        pos += 1
        for rep in (1, 2):
            steps.append(Step(pos, "trial", cond, block, rep, trial_index, time_limit,
                              data={"placement": {"sites": placements[trial_index - 1]}}))
            pos += 1
            trial_index += 1
            if rep == 1:
                steps.append(Step(pos, "break", cond, block, duration_s=30.0))
                pos += 1
        steps.append(Step(pos, "questionnaire", cond, block, data={"instrument": "ease", "when": "after_condition"}))
        pos += 1
    steps.append(Step(pos, "questionnaire", None, None, data={"instrument": "final", "when": "end"}))
    steps.append(Step(pos + 1, "end"))
    return SessionPlan(
        steps=tuple(steps),
        conditions=conds,
        instruments={"ease": instrument, "final": final},
        report=ReportSpec("grid", columns=("1", "2", "3"), rows=("1", "2", "3")),
        scene="toy_scene",
        simulated_device={"plugin": "toy_device", "params": {}},
        virtual_participant={"plugin": "toy_participant", "params": {}},
        interrupted_trial=policy,
        checkpoint=checkpoint,
        study="toy",
    )


def reset_toys() -> None:
    ToyDevice.disconnect_at = None
    ToyDevice.instances.clear()
    ToyParticipant.crash_at = None
    ToyParticipant.interrupt_at = None


def outcome_view(outcomes: Mapping[int, Mapping[str, Any]]) -> list[dict[str, Any]]:
    return [dict(v) for _, v in sorted(outcomes.items())]
