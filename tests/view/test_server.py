"""The view's server and hub without a browser: who may connect, who may answer, what is logged."""

from __future__ import annotations

import time

import numpy as np
import pytest
from http_client import Stream, request
from view_support import wait_for

from studyctl.engine.plan import ReportSpec
from studyctl.errors import UsageError
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo
from studyctl.view import FrameState, ParticipantView, ViewServer
from studyctl.view.frontend import ViewParticipant, _trial_rows
from studyctl.view.hub import CONTROL_GRACE_S, TrialView, ViewHub


@pytest.fixture
def view():
    with ParticipantView() as v:
        yield v


def refusals(view) -> list[dict]:
    return [p for k, p in view.hub.drain_log() if k == "view_refused"]


def test_page_served_with_strict_headers(view):
    status, body, headers = request(view, "GET", "")
    assert status == 200 and "<script src=\"view.js\">" in body
    assert "default-src 'none'" in headers["Content-Security-Policy"]
    assert headers["Referrer-Policy"] == "no-referrer" and headers["Cache-Control"] == "no-store"
    assert request(view, "GET", "view.js")[0] == 200 and request(view, "GET", "nothing")[0] == 404
    assert view.url.startswith("http://127.0.0.1:") and view.server.token in view.url
    assert refusals(view) == []


@pytest.mark.parametrize(
    ("method", "headers", "body", "reason"),
    [
        ("GET", {"Host": "evil.example:80"}, None, "host"),  # DNS rebinding
        ("GET", {"Sec-Fetch-Site": "cross-site"}, None, "cross_site"),
        ("GET", {"Origin": "http://evil.example"}, None, "origin"),
        ("POST", {"Origin": "http://evil.example"}, {"kind": "finish"}, "origin"),
        ("POST", {"Origin": None}, {"kind": "finish"}, "origin_missing"),
        ("POST", {"Content-Type": "text/plain"}, {"kind": "finish"}, "content_type"),
        ("OPTIONS", {"Origin": "http://evil.example"}, None, "origin"),  # a CORS preflight
    ],
)
def test_foreign_requests_are_refused_and_logged(view, method, headers, body, reason):
    hdrs = {k: v for k, v in headers.items() if v is not None}
    status, text, _ = request(view, method, "input" if method != "GET" else "", body, headers=hdrs,
                              origin=headers.get("Origin", "") is not None)
    assert status == 403 and "refused" in text
    logged = refusals(view)
    assert [p["reason"] for p in logged] == [reason]
    assert view.server.token not in str(logged)
    assert view.hub.inbox == type(view.hub.inbox)()  # nothing reached the session


def test_wrong_token_is_refused_logged_and_redacted(view):
    status, _, _ = request(view, "GET", "stream?client=x", token="A" * 22)
    assert status == 403
    status, _, _ = request(view, "POST", "input", {"kind": "scan"}, token="B" * 22)
    assert status == 403
    logged = refusals(view)
    assert [p["reason"] for p in logged] == ["wrong_token", "wrong_token"]
    assert logged[0]["path"] == "/v/AAAA…/stream" and logged[1]["method"] == "POST"
    assert view.hub.refusals == 2


def test_only_loopback_and_real_tokens():
    hub = ViewHub()
    for host in ("0.0.0.0", "192.168.1.5", "example.org"):
        with pytest.raises(UsageError, match="this machine only"):
            ViewServer(hub, host=host)
    with pytest.raises(UsageError, match="16 URL-safe"):
        ViewServer(hub, token="short")
    server = ViewServer(hub, token="a" * 16)
    server.stop()  # never started: stops without waiting


def test_second_screen_is_read_only_and_control_survives_a_reload(view):
    a = Stream(view, "aaaa")
    wait_for(lambda: a.of("hello"), 5, "hello a")
    b = Stream(view, "bbbb")
    wait_for(lambda: b.of("hello"), 5, "hello b")
    assert a.of("hello")[0]["role"] == "control" and b.of("hello")[0]["role"] == "read_only"
    view.hub.begin_trial(TrialView("on_request", ("scan", "finish"), ReportSpec(), 90.0))
    view.hub.show("trial")
    status, reply, _ = request(view, "POST", "input", {"client": "bbbb", "kind": "scan"})
    assert status == 403 and "read-only" in reply["error"]
    assert not view.hub.inbox
    # the controlling page reloads: its stream drops and comes back with the same client id
    a.close()
    wait_for(lambda: view.hub.clients["aaaa"].streams == 0, 5, "disconnect seen")
    a2 = Stream(view, "aaaa")
    wait_for(lambda: a2.of("hello"), 5, "hello again")
    assert a2.of("hello")[0]["role"] == "control"
    assert request(view, "POST", "input", {"client": "aaaa", "kind": "scan"})[0] == 200
    assert list(view.hub.inbox) == [Request("scan")]
    log = view.hub.drain_log()
    inputs = [p for k, p in log if k == "view_input"]
    assert [(p["client"], p["accepted"]) for p in inputs] == [("bbbb", False), ("aaaa", True)]
    actions = [p["action"] for k, p in log if k == "view_client"]
    assert actions[:2] == ["connected", "connected"] and "reconnected" in actions
    for s in (a2, b):
        s.close()


def test_control_passes_on_when_its_screen_is_gone_for_good():
    now = [100.0]
    hub = ViewHub(clock=lambda: now[0])
    assert hub.connect("a", "") == "control" and hub.connect("b", "") == "read_only"
    hub.disconnect("a")
    now[0] += CONTROL_GRACE_S / 2
    hub.maintain()
    assert hub.role("b") == "read_only"  # a reload may still come back
    now[0] += CONTROL_GRACE_S
    hub.maintain()
    assert hub.role("b") == "control" and hub.role("a") == "read_only"
    assert ("view_client", "control_released") in [(k, p.get("action")) for k, p in hub.drain_log()]


def _hub_with_controller() -> ViewHub:
    hub = ViewHub()
    hub.connect("c", "test")
    hub.drain_log()
    return hub


def test_likert_answers_are_checked_once_and_taken_once():
    hub = _hub_with_controller()
    hub.answerable = True
    pid = hub.show("item", prompt="likert", codes=(1, 2, 3, 4, 5))
    assert hub.submit("c", {"kind": "likert", "prompt": pid, "code": 9})[0] == 400
    assert hub.submit("c", {"kind": "likert", "prompt": pid, "code": True})[0] == 400
    assert hub.submit("c", {"kind": "likert", "prompt": pid - 1, "code": 4})[0] == 409  # an old question
    assert hub.take_answer() is None
    assert hub.submit("c", {"kind": "likert", "prompt": pid, "code": 4, "rt_s": 1.5})[0] == 200
    assert hub.submit("c", {"kind": "likert", "prompt": pid, "code": 5})[0] == 409  # double click
    assert hub.take_answer() == "4" and hub.take_answer() is None
    assert hub.prompt.page_rt_s == 1.5 and hub.prompt.client == "c"
    hub.answerable = False  # scripted sessions: the view shows prompts but does not answer them
    pid = hub.show("item", prompt="likert", codes=(1, 2))
    status, reply = hub.submit("c", {"kind": "likert", "prompt": pid, "code": 1})
    assert status == 409 and "terminal" in reply["error"]


def test_trial_requests_follow_the_condition_and_the_report_rules():
    hub = _hub_with_controller()
    assert hub.submit("c", {"kind": "scan"})[0] == 409  # no trial running
    spec = ReportSpec("position", bounds_mm=(0.0, 120.0, 0.0, 120.0))
    hub.begin_trial(TrialView("realtime", ("report", "finish"), spec, 60.0))
    hub.show("trial")
    status, reply = hub.submit("c", {"kind": "scan"})
    assert status == 409 and "not part of this study" in reply["error"]
    status, reply = hub.submit("c", {"kind": "report", "text": "130 5"})
    assert status == 400 and "outside the tissue" in reply["error"]
    assert hub.submit("c", {"kind": "report", "text": "30.5, 40"}) == (200, {"ok": True, "report": {
        "x_mm": 30.5, "y_mm": 40.0}})
    assert hub.submit("c", {"kind": "finish"})[0] == 200
    assert list(hub.inbox) == [Request("report", {"x_mm": 30.5, "y_mm": 40.0}), Request("finish")]
    hub.begin_trial(TrialView("realtime", ("scan", "finish"), ReportSpec(), 60.0))
    status, reply = hub.submit("c", {"kind": "scan"})
    assert status == 409 and "continuously" in reply["error"]
    assert not hub.inbox  # a new trial starts with an empty inbox


class _Inner(Participant):
    name = "inner"
    virtual = False

    def __init__(self) -> None:
        super().__init__()
        self.seen: list = []

    def begin_trial(self, info, rng) -> None:
        self.info = info

    def act(self, t, percept):
        self.seen.append((t, dict(percept)))
        return Action({"x_mm": t}, (Request("report", {"x_mm": 1.0, "y_mm": 2.0}),) if t == 0.002 else ())


@pytest.mark.slow
def test_view_participant_slots_frames_and_adds_requests():
    hub = ViewHub()
    inner = _Inner()
    vp = ViewParticipant(inner, hub)
    info = TrialInfo("ES", 90.0, 1000.0, "on_request", {"requests": ["scan", "finish"], "report": {"kind": "none"}})
    vp.begin_trial(info, np.random.default_rng(0))
    assert hub.trial.visual == "on_request" and hub.screen["requests"] == ["scan", "finish"]
    assert vp.act(0.000, {}).requests == ()
    scan = {"kind": "ct", "image": np.zeros((2, 2), np.uint8)}
    hub.inbox.append(Request("scan"))
    action = vp.act(0.001, {"scan": scan})
    assert action.inputs == {"x_mm": 0.001} and action.requests == (Request("scan"),)
    state = hub.latest
    assert isinstance(state, FrameState) and state.source == "scan" and state.count == 1
    assert state.t == 0.000 and state.frame is scan and state.ts <= time.perf_counter()
    action = vp.act(0.002, {"view": {"x": 1.0}})
    assert [r.kind for r in action.requests] == ["report"]  # the inner participant's own requests stay
    assert hub.latest.source == "view" and hub.latest.t == 0.001 and hub.latest.seq == 2
    assert vp.name == "inner" and vp.virtual is False and inner.seen[1][1] == {"scan": scan}


@pytest.mark.slow
def test_trial_log_rows_scans_one_by_one_frames_in_batches():
    trial = TrialView("realtime", ("finish",), ReportSpec(), 10.0)
    trial.log += [{"seq": i, "source": "view", "state_t": i / 60, "drawn_t": i / 60 + 0.02, "latency_ms": 20.0 + i,
                   "client": "c"} for i in range(1, 1300)]
    trial.log.append({"seq": 9999, "source": "scan", "state_t": 3.0, "drawn_t": 3.03, "latency_ms": 30.0,
                      "client": "c"})
    rows = _trial_rows(trial, 7)
    kinds = [r[0] for r in rows]
    assert kinds.count("view_scan_shown") == 1 and kinds.count("view_frames") == 3
    frames = [r for r in rows if r[0] == "view_frames"]
    assert [r[1]["n"] for r in frames] == [600, 600, 99] and all(r[3] == 7 for r in rows)
    assert frames[0][1]["seq"][:3] == [1, 2, 3] and frames[0][2] == pytest.approx(1 / 60 + 0.02)
