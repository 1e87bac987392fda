"""The coordinator's read-only page beside the participant view: it names the condition (the participant's page
never does), follows the protocol step by step, serves only GET on a token of its own, and in a real browser
shows a running session live (loop rate, trial timer, lease, a note typed in another terminal)."""

from __future__ import annotations

import json
import os
import re
from types import SimpleNamespace

import pytest
from http_client import request
from test_blinding import PROTOCOLS, _Inner, leaks
from view_support import _full_plan, wait_for

from studyctl.view import ParticipantView
from studyctl.view.board import CoordinatorBoard
from studyctl.view.frontend import ViewUI
from studyctl.view.hub import ViewHub


class _State(SimpleNamespace):
    def attempts(self, position):
        return []


class _Rec:
    """The parts of a session recorder the view and the board read: the session's state (steps done)."""

    def __init__(self, plan):
        self._state = _State(session_id=7, participant="P-TEST", plan=plan, completed=set(), trials=[],
                             virtual=False, rehearsal=False, resumes=0)
        self.session_id = 7

    def state(self):
        return self._state

    def event(self, *a, **k): ...


def _walk(plan):
    """Run every step of ``plan`` through the view's UI; at each trial, what each page holds at that moment."""
    hub = ViewHub()
    board = CoordinatorBoard(hub)
    rec = _Rec(plan)
    ui = ViewUI(_Inner(), hub, rec, board)
    seen = []
    for step in plan.steps:
        if step.kind in ("instructions", "end"):
            ui.instructions(step, str(step.data.get("text", "")))
        elif step.kind == "break":
            ui.timer("Break", 1.0, None, can_end_early=False, purpose="break")
        elif step.kind == "trial" and plan.conditions[step.condition].manual:
            ui.manual_outcome(step, plan.report, None)
            seen.append((step, dict(hub.screen), board.snapshot()))
        elif step.kind == "trial":
            ui.trial_begin(step, step.duration_s or 1800.0)
            seen.append((step, dict(hub.screen), board.snapshot()))
            ui.trial_end(step, {"status": "completed", "ended_by": "finish", "duration_s": 1.0})
        elif step.kind == "questionnaire":
            inst = plan.instruments[step.data["instrument"]]
            ui.ask_item(inst, inst.items[0], 1, {"position": step.position})
        rec.state().completed.add(step.position)
    return seen, board


@pytest.mark.parametrize("name", PROTOCOLS)
def test_the_coordinator_sees_each_condition_the_participant_never_does(name):
    plan = _full_plan(name)
    seen, board = _walk(plan)
    trials = [s for s in plan.steps if s.kind == "trial"]
    assert len(seen) == len(trials)
    for k, (step, screen, snap) in enumerate(seen):
        json.dumps(snap, allow_nan=False)  # the page's JSON
        assert snap["progress"]["condition"]["code"] == step.condition, step.label()
        assert snap["progress"]["step"]["position"] == step.position
        assert snap["progress"]["trials"] == {"planned": len(trials), "done": k, "left": len(trials) - k,
                                              "completed": 0, "aborted": 0, "invalid": 0}
        current = [r for r in snap["progress"]["steps"] if r["state"] == "current"]
        assert [r["position"] for r in current] == [step.position]
        assert leaks([screen], dict(plan.conditions)) == []  # the same moment on the participant's page
    assert board.snapshot()["phase"]["kind"] == "done"


def test_loop_events_and_rate_reach_the_board():
    plan = _full_plan("needle_insertion")
    hub = ViewHub(clock=lambda: now[0])
    now = [100.0]
    board = CoordinatorBoard(hub, clock=hub.clock)
    ui = ViewUI(_Inner(), hub, _Rec(plan), board)
    step = next(s for s in plan.steps if s.kind == "trial")
    ui.trial_begin(step, 90.0)
    hub.trial = SimpleNamespace(scans=0, reports=0)
    ui.trial_event(0.0, "trial_loop_start", {"rate_hz": 1000.0})
    ui.trial_event(0.5, "scan", {"count": 1})
    ui.trial_event(0.9, "scan", {"count": 2})
    ui.trial_event(1.4, "device_fault", {"rule": "missed_deadline", "missed": 7})
    ui.trial_event(1.45, "device_recovered", {"rule": "missed_deadline"})
    ui.trial_event(1.5, "device_fault", {"rule": "sensor_stale"})
    assert board.snapshot()["device"]["fault_active"]["rule"] == "sensor_stale"
    ui.trial_event(1.6, "device_recovered", {"rule": "sensor_stale"})
    for i in range(1, 6):  # 1000 ticks per 0.5 s of the page's clock
        hub.tick = (1.6 + 0.5 * i, now[0], 1000 * i)
        snap = board.snapshot()
        now[0] += 0.5
    loop = snap["loop"]
    assert loop["rate_hz"] == pytest.approx(2000.0) and loop["target_hz"] == 1000.0 and loop["scans"] == 2
    assert loop["t"] == pytest.approx(4.1) and loop["time_limit_s"] == step.duration_s and not loop["stalled"]
    dev = snap["device"]
    assert dev["fault_active"] is None and dev["trial"] == {"device_fault": 2, "device_recovered": 2, "late_ticks": 7}
    assert [e["rule"] for e in dev["events"]] == ["missed_deadline"] * 2 + ["sensor_stale"] * 2
    assert loop["samples"] is None  # a tick without the trial's own count (older callers): not guessed
    now[0] += 1.0  # no tick for a second: a stalled loop
    assert board.snapshot()["loop"]["stalled"]
    # the trial's own tick count against its rate: 4.5 s at 1000 Hz is 4500 samples; 4200 taken
    hub.tick = (4.5, now[0], 5200, 4200)
    loop = board.snapshot()["loop"]
    assert (loop["samples"], loop["samples_behind"]) == (4200, 300) and not loop["stalled"]


def test_served_read_only_on_its_own_token():
    with ParticipantView() as view:
        ctoken = view.server.coord_token
        assert ctoken != view.server.token and ctoken in view.coordinator_url and view.server.token not in \
            view.coordinator_url
        status, body, headers = request(view, "GET", "", token=ctoken, path="c")
        assert status == 200 and '<script src="coordinator.js">' in body and "read-only" in body
        assert "default-src 'none'" in headers["Content-Security-Policy"]
        assert request(view, "GET", "coordinator.js", token=ctoken, path="c")[0] == 200
        status, state, _ = request(view, "GET", "state", token=ctoken, path="c")
        assert status == 200 and state["phase"]["kind"] == "waiting" and state["progress"] is None
        # the participant's token does not open the coordinator's page, nor the other way round
        assert request(view, "GET", "state", path="c")[0] == 403
        assert request(view, "GET", "", token=ctoken)[0] == 403
        # nothing can be sent to it
        for method in ("POST", "PUT", "DELETE"):
            status, text, _ = request(view, method, "state", {"kind": "finish"}, token=ctoken, path="c")
            assert status == 405 and "read-only" in text, method
        reasons = [p["reason"] for k, p in view.hub.drain_log() if k == "view_refused"]
        assert reasons == ["wrong_token", "wrong_token"] and ctoken not in str(view.hub.pending_log)
        # once the view closes, the page is told so (and stops polling)
        view.server.stopping = True
        assert request(view, "GET", "state", token=ctoken, path="c")[0] == 410
        view.server.stopping = False
        # the participant's page and script never carry the coordinator's address
        assert ctoken not in request(view, "GET", "")[1] and ctoken not in request(view, "GET", "view.js")[1]


@pytest.mark.slow
def test_coordinator_page_live_beside_the_participant_view(store, browser, new_browser, shots):
    from selenium.webdriver.common.by import By
    from test_browser import assert_blind, caption, click, wait_screen
    from view_support import TissueHand, short_plan, start_session

    from studyctl.store.coordination import add_note
    from studyctl.store.lease import take_lease

    plan = short_plan("pseudo_haptic_palpation", "PHF", time_limit_s=60.0, questionnaire=False)
    trial_step = next(s for s in plan.steps if s.kind == "trial")
    placement = dict(trial_step.data["placement"])
    coord = new_browser()
    with ParticipantView() as view:
        run = start_session(store, plan, lambda: TissueHand(dict(plan.scene_spec), placement), view)
        coord.get(view.coordinator_url)
        text = lambda: coord.find_element(By.TAG_NAME, "main").text  # noqa: E731
        wait_for(lambda: "instructions" in coord.find_element(By.ID, "phase").text, 10, "the instructions phase")
        browser.get(view.url)
        wait_screen(browser, "instructions")
        click(browser, "#btn-ready")
        wait_screen(browser, "trial_ready")
        wait_for(lambda: coord.find_element(By.ID, "cond-code").text == "PHF", 10, "the condition code")
        click(browser, "#btn-start")
        wait_screen(browser, "trial")
        wait_for(lambda: caption(browser) == "live", 10, "live frames")
        sid = run.recorder.session_id
        with store.in_transaction() as tx:  # as `studyctl run` holds it (the test helper's recorder does not)
            lease = take_lease(store.db, tx, sid)
        add_note(store, "participant adjusted the chair", session=sid, study=store.get_study(None).name)
        wait_for(lambda: "adjusted the chair" in text(), 10, "the note on the page")
        wait_for(lambda: "held by pid" in coord.find_element(By.ID, "lease").text, 10, "the lease owner")
        # the whole study (what `studyctl status` shows): this participant's row, by condition
        wait_for(lambda: "P001" in coord.find_element(By.ID, "study-table").text, 15, "the study's progress")
        study = coord.execute_script("return window.studyctlCoordinator.state().study")
        assert [p["code"] for p in study["people"]] == ["P001"] and study["people"][0]["cells"]["PHF"] == [0, 0]
        wait_for(lambda: re.search(r"\d+ Hz of \d+ Hz", coord.find_element(By.ID, "loop-rate").text), 10,
                 "a measured loop rate")
        state = coord.execute_script("return window.studyctlCoordinator.state()")
        assert state["phase"]["kind"] == "trial" and state["progress"]["condition"]["code"] == "PHF"
        assert state["loop"]["running"] and state["loop"]["rate_hz"] > 0 and state["loop"]["t"] > 0
        assert state["lease"]["pid"] == os.getpid() and state["lease"]["heartbeat_age_s"] >= 0
        assert re.fullmatch(r"\d:\d\d", coord.find_element(By.ID, "timer-value").text)
        assert coord.find_element(By.ID, "t-done").text == "0 of 1"
        assert coord.find_element(By.ID, "ps-clients").text.startswith("1")
        # the running trial's samples against its rate, and the study's dropped samples and missing data
        assert re.fullmatch(r"\d+ · \d+ behind the rate", coord.find_element(By.ID, "loop-samples").text)
        assert state["loop"]["samples"] > 0 and state["loop"]["samples_behind"] >= 0
        assert re.match(r"data: 0 of 0 loop samples stored in 0 ended trials \(0 dropped\) · missing: 0 trials, "
                        r"0 questionnaire answers", coord.find_element(By.ID, "study-data").text)
        # the participant's page, at the same moment, holds no condition code or name
        assert_blind(browser, plan)
        assert "PHF" not in browser.page_source and view.server.coord_token not in browser.page_source
        for w, h in ((1280, 900), (1920, 1080)):
            coord.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                                  {"width": w, "height": h, "deviceScaleFactor": 1, "mobile": False})
            wait_for(lambda: coord.execute_script("return document.body.dataset.conn") == "ok", 5, "live")
            overflow = coord.execute_script("return document.documentElement.scrollWidth > innerWidth")
            assert not overflow, (w, h)
            shots(coord, f"20_coordinator_trial_{w}x{h}")
        shots(browser, "21_participant_same_moment")
        click(browser, "#btn-finish")
        wait_screen(browser, "done", 15)
        wait_for(lambda: coord.find_element(By.ID, "t-done").text == "1 of 1", 10, "the trial counted as done")
        shots(coord, "22_coordinator_done")
        result = run.wait()
        lease.release()
    run.pty.close()
    wait_for(lambda: coord.execute_script("return document.body.dataset.conn") == "lost", 5, "the page sees the end")
    coord.quit()
    assert result.status == "completed"
