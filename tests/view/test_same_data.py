"""Same data either way: a session answered in the participant view and one answered at the coordinator's
terminal (the engine's real TerminalUI on a pseudo-terminal) leave the same records."""

from __future__ import annotations

import pytest
from http_client import Stream, request
from view_support import NeedleHand, short_plan, start_session, wait_for

from studyctl.view import ParticipantView

pytestmark = pytest.mark.slow


def _screen(view, name: str) -> dict:
    return wait_for(lambda: view.hub.screen if view.hub.screen.get("screen") == name else None, 15, name)


def _answer_in_view(view) -> None:
    page = Stream(view, "page")
    try:
        for screen, kind in (("instructions", "ready"), ("trial_ready", "start")):
            prompt = _screen(view, screen)["prompt"]
            assert prompt["answerable"]
            assert request(view, "POST", "input", {"client": "page", "kind": kind, "prompt": prompt["id"]})[0] == 200
        wait_for(lambda: view.hub.trial is not None and view.hub.screen.get("screen") == "trial", 10, "trial")
        assert request(view, "POST", "input", {"client": "page", "kind": "scan"})[0] == 200
        wait_for(lambda: view.hub.latest is not None and view.hub.latest.source == "scan", 10, "the scan")
        assert request(view, "POST", "input", {"client": "page", "kind": "finish"})[0] == 200
        prompt = _screen(view, "item")["prompt"]
        body = {"client": "page", "kind": "likert", "prompt": prompt["id"], "code": 4}
        assert request(view, "POST", "input", body)[0] == 200
    finally:
        page.close()


def _answer_at_terminal(view, pty) -> None:
    _screen(view, "instructions")
    pty.type("\n")
    _screen(view, "trial_ready")
    pty.type("\n")
    wait_for(lambda: view.hub.trial is not None and view.hub.screen.get("screen") == "trial", 10, "trial")
    pty.type("s")
    wait_for(lambda: view.hub.latest is not None and view.hub.latest.source == "scan", 10, "the scan")
    pty.type("f")
    _screen(view, "item")
    pty.type("4\n")


def _records(store, sid):
    resp = store.responses_frame()
    resp = resp[resp.session_id == sid]
    answers = sorted(zip(resp.instrument, resp.instrument_version, resp.item, resp.code, resp.context, strict=True))
    events = store.events_frame(sid)
    answer_events = [{k: v for k, v in p.items() if k != "response_time_s"}
                     for p in events[events.kind == "answer"].payload]
    scans = [sorted(p) for p in events[events.kind == "scan"].payload]
    trial = next(t for t in store.list_trials(session_id=sid) if t.outcome.get("ticks"))
    outcome = {k: trial.outcome[k] for k in ("ended_by", "scans", "reports", "rejected_reports", "attempt", "step")}
    steps = [(k, p.get("position")) for k, p in zip(events.kind, events.payload, strict=True)
             if k in ("step_enter", "step_done")]
    sources = [p["source"] for p in events[events.kind == "view_answer"].payload]
    return answers, answer_events, scans, (trial.status, outcome), steps, sources


def test_view_and_terminal_answers_make_the_same_records(store):
    plan = short_plan("needle_insertion", "ES", time_limit_s=30.0)
    placement = dict(next(s for s in plan.steps if s.kind == "trial").data["placement"])
    results = {}
    for how in ("view", "terminal"):
        with ParticipantView() as view:
            run = start_session(store, plan, lambda: NeedleHand(placement), view, code=f"P-{how}")
            try:
                _answer_in_view(view) if how == "view" else _answer_at_terminal(view, run.pty)
                result = run.wait()
            finally:
                run.pty.close()
        assert result.status == "completed"
        results[how] = _records(store, result.session_id)
    view_rec, term_rec = results["view"], results["terminal"]
    assert view_rec[0] == term_rec[0] == [("scenario_experience", "2024.1", "improved_vs_baseline", 4, "step:3")]
    assert view_rec[1] == term_rec[1] and len(view_rec[1]) == 1
    assert view_rec[2] == term_rec[2] and len(view_rec[2]) == 1
    assert view_rec[3] == term_rec[3] and view_rec[3][0] == "completed" and view_rec[3][1]["scans"] == 1
    assert view_rec[3][1]["ended_by"] == "finish"
    assert view_rec[4] == term_rec[4]
    # only the view's own log says where the answers came from
    assert set(view_rec[5]) == {"view"} and set(term_rec[5]) == {"terminal"} and len(view_rec[5]) == 3
