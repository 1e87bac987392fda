"""Blinding: the participant's page never receives a condition code or name.

Every step of each reference protocol's plan goes through the view's UI as the session runner would
call it; every screen body the server would stream (``hub.screen``, sent as-is in the SSE ``screen``
message) is collected and searched for the protocol's condition ids and labels."""

from __future__ import annotations

import json
import re
import time
from types import SimpleNamespace

import pytest
from view_support import _full_plan

from studyctl.engine.plan import ConditionSpec
from studyctl.engine.ui import ManualOutcome, TimerResult
from studyctl.view.frontend import ViewUI
from studyctl.view.hub import ViewHub

PROSE = ("text", "intro")
PROTOCOLS = ["bio_inspired_palpation", "needle_insertion", "data_driven_palpation", "pseudo_haptic_palpation"]


class _Inner:
    """A coordinator UI that answers at once (the view only mirrors what it is asked)."""

    interactive = False

    def message(self, text): ...
    def instructions(self, step, text): ...
    def timer(self, title, duration_s, clock, *, can_end_early, purpose):
        return TimerResult(elapsed_s=duration_s, ended_early=False, paused_s=0.0)
    def ask_item(self, instrument, item, number, context):
        return item.codes()[0], 1.0
    def manual_outcome(self, step, report, clock):
        return ManualOutcome(duration_s=1.0, reports=())
    def trial_begin(self, step, time_limit_s): ...
    def trial_tick(self, t): ...
    def trial_end(self, step, summary): ...
    def poll_control(self): return None
    def wait_unpause(self): ...
    def close(self): ...


class _Rec:
    """Just enough of the session recorder for the view: the plan and no stored attempts."""

    def __init__(self, plan):
        self._state = SimpleNamespace(plan=plan, attempts=lambda position: [])

    def state(self):
        return self._state

    def event(self, *a, **k): ...


def drive(plan, hub: ViewHub | None = None, after=None) -> list[dict]:
    """Every screen body the page would receive while ``plan`` runs (``after(body)`` is called with each)."""
    hub = hub or ViewHub()
    seen: list[dict] = []
    show, update = hub.show, hub.update

    def show_and_keep(*a, **k):
        out = show(*a, **k)
        seen.append(dict(hub.screen))
        if after is not None:
            after(seen[-1])
        return out

    def update_and_keep(**k):
        update(**k)
        seen.append(dict(hub.screen))
        if after is not None:
            after(seen[-1])

    hub.show, hub.update = show_and_keep, update_and_keep
    ui = ViewUI(_Inner(), hub, _Rec(plan))
    for step in plan.steps:
        if step.kind in ("instructions", "end"):
            ui.instructions(step, str(step.data.get("text", "")))
        elif step.kind == "break":
            ui.timer("Break", 1.0, None, can_end_early=False, purpose="break")
        elif step.kind == "familiarisation":
            if step.data.get("instructions"):
                ui.instructions(step, str(step.data["instructions"]))
            # the engine's own title names the condition: the view must not pass it on
            label = plan.conditions[step.condition].label
            ui.timer(f"Familiarisation: {label}", 1.0, None, can_end_early=True, purpose="familiarisation")
            ui.trial_begin(step, float("inf"))
            ui.trial_end(step, {"status": "completed", "ended_by": "finish", "duration_s": 1.0})
        elif step.kind == "trial":
            if plan.conditions[step.condition].manual:
                ui.manual_outcome(step, plan.report, None)
                continue
            ui.trial_begin(step, step.duration_s or 1800.0)
            ui.trial_end(step, {"status": "completed", "ended_by": "finish", "duration_s": 1.0})
        elif step.kind == "questionnaire":
            inst = plan.instruments[step.data["instrument"]]
            for n, item in enumerate(inst.items, start=1):
                ui.ask_item(inst, item, n, {"position": step.position})
    return seen


def leaks(screens: list[dict], conditions: dict[str, ConditionSpec]) -> list[str]:
    found = []
    for body in screens:
        text = json.dumps(body, ensure_ascii=False)
        # The protocol's own prose for participants (study-wide instructions) may use a plain word that is
        # also an id ("haptic palpation of a tissue model"); every other field is checked for ids too.
        fields = json.dumps({k: v for k, v in body.items() if k not in PROSE}, ensure_ascii=False)
        if "condition" in body:
            found.append(f"condition field in {text[:120]}")
        for c in conditions.values():
            # ids as whole words, case-sensitive ("ES", "manual"); labels anywhere, any case
            if re.search(rf"(?<![A-Za-z0-9_]){re.escape(c.id)}(?![A-Za-z0-9_])", fields):
                found.append(f"id {c.id!r} in {text[:160]}")
            if c.label and c.label.lower() in text.lower():
                found.append(f"label {c.label!r} in {text[:160]}")
    return found


@pytest.mark.parametrize("name", PROTOCOLS)
def test_no_condition_code_or_name_reaches_the_page(name):
    plan = _full_plan(name)
    screens = drive(plan)
    kinds = {s["screen"] for s in screens}
    assert {"instructions", "done"} <= kinds and ({"trial", "hands_on"} & kinds)
    assert leaks(screens, dict(plan.conditions)) == []
    trials = [s for s in screens if s["screen"] in ("trial_ready", "trial") and not s.get("practice")]
    assert trials and all(re.fullmatch(r"Trial \d+", s["label"]) for s in trials)


def test_the_leak_check_sees_a_code_and_a_protocol_label_is_shown():
    plan = _full_plan("pseudo_haptic_palpation")
    # the check itself can fail: a condition's label on the page is found
    assert leaks([{"screen": "trial", "title": plan.conditions["PHF"].label}], dict(plan.conditions))
    assert leaks([{"screen": "trial", "label": "Trial 1 · PHF_FF"}], dict(plan.conditions))
    # a protocol's neutral view_label is what the page shows beside the trial number
    labelled = {k: ConditionSpec(**{**v.__dict__, "view_label": f"Session {chr(65 + i)}"})
                for i, (k, v) in enumerate(plan.conditions.items())}
    import dataclasses

    plan = dataclasses.replace(plan, conditions=labelled)
    screens = drive(plan)
    assert leaks(screens, labelled) == []
    labels = {s["label"] for s in screens if s["screen"] == "trial" and not s.get("practice")}
    assert labels and all(re.fullmatch(r"Trial \d+ · Session [A-D]", x) for x in labels)


def test_no_countdown_limit_without_a_protocol_limit():
    # The pseudo-haptic protocol sets no limit: the engine's unattended cap must not become a 30:00 clock.
    screens = drive(_full_plan("pseudo_haptic_palpation"))
    assert all(s.get("time_limit_s") is None for s in screens if s["screen"] == "trial")
    screens = drive(_full_plan("needle_insertion"))
    assert {s.get("time_limit_s") for s in screens if s["screen"] == "trial" and not s.get("practice")} == {90.0}



@pytest.mark.slow
@pytest.mark.parametrize("name", PROTOCOLS)
def test_the_page_in_chromium_shows_no_condition_and_no_clock_without_a_limit(name, browser, shots):
    """Each reference protocol's every screen, rendered by the real page in headless Chromium: its visible text holds
    no condition id (outside the protocol's own prose) or label, and the trial countdown shows only with a limit."""
    from test_browser import at_sizes
    from view_support import wait_for

    from studyctl.view import ParticipantView

    plan = _full_plan(name)
    conditions = dict(plan.conditions)
    problems: list[str] = []
    shown = {"screens": 0, "clocks": 0, "limited": 0}

    def check(body: dict) -> None:
        want = json.loads(json.dumps(body))
        def on_page() -> bool:  # the screen the page holds (the server numbers each screen's version)
            screen = browser.execute_script("return window.studyctlView.state().screen") or {}
            return {k: v for k, v in screen.items() if k != "version"} == want

        wait_for(on_page, 15, f"the page to show {body['screen']}")
        text = browser.execute_script("return document.body.innerText")
        for prose in (body.get(k) for k in PROSE):
            if isinstance(prose, str):
                text = text.replace(prose.strip(), " ")
        # ids as whole words (case-sensitive); labels anywhere, any case: as the hub-level check above
        problems.extend(f"{body['screen']}: {text[:100]!r} holds {c.id!r} or {c.label!r}" for c in conditions.values()
                        if re.search(rf"(?<![A-Za-z0-9_]){re.escape(c.id)}(?![A-Za-z0-9_])", text)
                        or (c.label and c.label.lower() in text.lower()))
        if body["screen"] == "trial":
            limited = bool(body.get("time_limit_s"))
            shown["limited"] += limited
            # the page redraws its countdown every 100 ms: give it a few redraws either way
            end = time.monotonic() + (5.0 if limited else 0.5)
            while True:
                clock = browser.execute_script("return document.getElementById('countdown').textContent").strip()
                if (limited and clock) or time.monotonic() > end:
                    break
                time.sleep(0.05)
            shown["clocks"] += bool(clock)
            if bool(clock) != limited:
                problems.append(f"trial {body.get('label')}: countdown {clock!r} with time_limit_s "
                                f"{body.get('time_limit_s')}")
        shown["screens"] += 1
        kind = body["screen"] + ("_practice" if body.get("practice") else "")
        # the first of each at 1920x1080 and 1280x720, everything inside the window (a trial's own screen needs the
        # running trial's visual and requests: test_browser.py shoots those from real sessions)
        if kind in ("hands_on", "trial_ready") and kind not in shown:
            shown[kind] = 1
            at_sizes(browser, shots, f"30_{name}_{kind}")

    with ParticipantView() as view:
        browser.get(view.url)
        wait_for(lambda: browser.execute_script("return window.studyctlView && window.studyctlView.state().screen"),
                 15, "the page connected")
        drive(plan, hub=view.hub, after=check)
        del view.hub.show, view.hub.update  # the hub's own again: closing the view shows its last screen
    assert problems == []
    assert shown["screens"] >= 19 and shown["clocks"] == shown["limited"]
    # of the four, only the needle protocol sets a trial time limit (90 s): a clock on each of its 15 trials
    assert shown["limited"] == (15 if name == "needle_insertion" else 0), shown
