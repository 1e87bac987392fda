"""Helpers for the participant-view tests: short plans cut from the shipped protocols, a terminal on a
pseudo-terminal (the coordinator's real TerminalUI), a scripted hand on the simulated device, and a
session running in a background thread while the test drives the browser."""

from __future__ import annotations

import dataclasses
import io
import math
import os
import pty
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from polling import wait_for  # noqa: F401  (the view tests import it from here)
from rich.console import Console

from studyctl.engine.clock import RealClock
from studyctl.engine.factory import EntryPointFactory
from studyctl.engine.person import TerminalParticipant
from studyctl.engine.planning import plan_for_participant
from studyctl.engine.session import SessionRunner
from studyctl.engine.store_recorder import StoreRecorder
from studyctl.engine.terminal import Terminal, TerminalUI
from studyctl.plugins.interfaces import Action
from studyctl.protocol.loader import load_protocol, resolve_protocol
from studyctl.protocol.schedule import Planner
from studyctl.scenes.needle_liver import NeedleLiverScene
from studyctl.scenes.tissue import StiffnessTissueScene
from studyctl.store import StudyStore


def _full_plan(protocol_name: str):
    protocol = load_protocol(resolve_protocol(protocol_name))
    schedule = Planner(protocol).expand(seed=int(protocol.study.seed or 1), slot=0, stratum=protocol.stratum_ids[0])
    return plan_for_participant(protocol, schedule)


def short_plan(protocol_name: str, condition: str, *, time_limit_s: float | None, questionnaire: bool = True):
    """Instructions → one trial of ``condition`` → (its first questionnaire, first item only) → end."""
    plan = _full_plan(protocol_name)
    steps = list(plan.steps)
    trial = next(s for s in steps if s.kind == "trial" and s.condition == condition)
    chosen = [steps[0], dataclasses.replace(trial, duration_s=time_limit_s, trial_index=1)]
    instruments = {}
    if questionnaire:
        q = next(s for s in steps if s.kind == "questionnaire")
        inst = plan.instruments[q.data["instrument"]]
        inst = dataclasses.replace(inst, items=inst.items[:1])
        instruments = {inst.id: inst}
        chosen.append(dataclasses.replace(q, condition=condition))
    chosen.append(steps[-1])
    chosen = [dataclasses.replace(s, position=i) for i, s in enumerate(chosen, start=1)]
    return dataclasses.replace(plan, steps=tuple(chosen), instruments=instruments, hardware_device=None)


class PtyTerminal:
    """The engine's :class:`Terminal` on a pseudo-terminal; the test types into :attr:`master`."""

    def __init__(self) -> None:
        self.master, slave = pty.openpty()
        self.slave = os.fdopen(slave, "r")
        self.out = io.StringIO()
        self.term = Terminal(console=Console(file=self.out, width=120, force_terminal=False, highlight=False),
                             stdin=self.slave)

    def type(self, text: str) -> None:
        os.write(self.master, text.encode())

    def close(self) -> None:
        self.term.restore()
        self.slave.close()
        os.close(self.master)


class NeedleHand(TerminalParticipant):
    """A person at the terminal whose hand slowly pushes the needle along the planned path."""

    name = "test_needle_hand"

    def __init__(self, placement: dict[str, Any], speed_mm_s: float = 8.0) -> None:
        super().__init__()
        g = NeedleLiverScene.build({}, placement, frozenset(), np.random.default_rng(0)).geometry()
        inc, c = np.array(g.incision_mm), np.array(g.tumour_center_mm)
        self.out_dir = (inc - c) / np.linalg.norm(inc - c)
        self.start = inc + 15.0 * self.out_dir
        self.speed = speed_mm_s

    def act(self, t, percept):
        action = super().act(t, percept)
        p = self.start - self.out_dir * min(self.speed * t, 60.0)
        d = -self.out_dir
        inputs = {"x_mm": p[0], "y_mm": p[1], "z_mm": p[2], "dir_x": d[0], "dir_y": d[1], "dir_z": d[2],
                  "button": 1.0}
        return Action(inputs, action.requests)


class TissueHand(TerminalParticipant):
    """A person at the terminal whose hand presses into the tissue at its centre and moves sideways."""

    name = "test_tissue_hand"

    def __init__(self, spec: dict[str, Any], placement: dict[str, Any]) -> None:
        super().__init__()
        public = StiffnessTissueScene.build(spec, placement, frozenset(), np.random.default_rng(0)).public()
        self.x0, self.y0, z = public["start_mm"]
        self.top = z - 20.0

    def act(self, t, percept):
        action = super().act(t, percept)
        depth = min(6.0 * t, 4.0)  # press 4 mm in over the first 2/3 s, then hold
        x = self.x0 - 20.0 + 10.0 * math.sin(0.8 * t)
        return Action({"x_mm": x, "y_mm": self.y0, "z_mm": self.top + 5.0 - depth - 5.0}, action.requests)


@dataclasses.dataclass
class Running:
    thread: threading.Thread
    recorder: StoreRecorder
    result: dict[str, Any]
    pty: PtyTerminal

    def wait(self, timeout: float = 30.0) -> Any:
        self.thread.join(timeout)
        if self.thread.is_alive():
            raise AssertionError("the session did not finish in time")
        if "error" in self.result:
            raise self.result["error"]
        return self.result["value"]


def start_session(store: StudyStore, plan, hand_factory: Callable[[], TerminalParticipant], view, *,
                  code: str = "P001", seed: int = 3) -> Running:
    """Run ``plan`` for a person at a pseudo-terminal, with ``view`` attached, in a background thread."""
    study = store.create_study(f"view-{code}-{time.monotonic_ns()}", protocol_text=None, seed=1)
    person = store.add_participant(study.id, code)
    rec = StoreRecorder.create(store, person.id, plan, seed=seed, virtual=False)
    pt = PtyTerminal()
    tui = TerminalUI(pt.term)
    hand = hand_factory()
    hand.attach(pt.term, tui)
    participant, ui = view.attach(hand, tui, rec)
    runner = SessionRunner(rec, ui=ui, participant=participant, clock=RealClock(), factory=EntryPointFactory(),
                           virtual=False)
    result: dict[str, Any] = {}

    def target() -> None:
        try:
            result["value"] = runner.run()
        except BaseException as exc:  # reported by Running.wait
            result["error"] = exc
        finally:
            ui.close()

    thread = threading.Thread(target=target, name="session", daemon=True)
    thread.start()
    return Running(thread, rec, result, pt)



class PtyProcess:
    """A child process on a pseudo-terminal (a real coordinator's terminal); output is read continuously."""

    def __init__(self, args: list[str], cwd, env: dict[str, str]) -> None:
        pid, fd = pty.fork()
        if pid == 0:  # child
            os.chdir(cwd)
            os.execvpe(args[0], args, env)
        self.pid, self.fd = pid, fd
        self.out = ""
        self.status: int | None = None
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while True:
            try:
                data = os.read(self.fd, 65536)
            except OSError:
                return
            if not data:
                return
            self.out += data.decode("utf-8", "replace")

    def expect(self, pattern: str, timeout: float = 30.0):
        import re

        rx = re.compile(pattern)
        return wait_for(lambda: rx.search(self.out), timeout, f"{pattern!r} on the terminal (got …{self.out[-300:]!r})")

    def send(self, text: str) -> None:
        os.write(self.fd, text.encode())

    def wait(self, timeout: float = 30.0) -> int:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.status = os.waitstatus_to_exitcode(status)
                return self.status
            time.sleep(0.05)
        os.kill(self.pid, 9)
        raise AssertionError(f"the process did not end in {timeout} s; output: …{self.out[-500:]!r}")
