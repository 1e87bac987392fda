"""The session state machine on an in-memory recorder with toy plugins."""

from __future__ import annotations

import numpy as np
import pytest
from engine_toys import PLUGINS, Crash, ToyDevice, ToyParticipant, reset_toys, toy_plan

from studyctl.engine.clock import SimulatedClock
from studyctl.engine.factory import MappingFactory
from studyctl.engine.plan import SessionPlan
from studyctl.engine.recorder import MemoryRecorder
from studyctl.engine.seeding import answer_rng
from studyctl.engine.session import SessionRunner
from studyctl.engine.ui import Script, ScriptedUI, VirtualUI
from studyctl.errors import SessionError, SessionInterrupted


@pytest.fixture(autouse=True)
def _reset():
    reset_toys()
    yield
    reset_toys()


def runner(rec: MemoryRecorder, ui=None, participant=None) -> SessionRunner:
    participant = participant or ToyParticipant()
    seed = rec.state().seed
    ui = ui or VirtualUI(participant, lambda pos, n: answer_rng(seed, pos, n))
    return SessionRunner(rec, ui=ui, participant=participant, clock=SimulatedClock(),
                         factory=MappingFactory(PLUGINS), virtual=True)


def completed_trials(rec: MemoryRecorder) -> dict[int, dict]:
    """Completed trial outcomes by plan step position, with their reports (attempt numbers dropped)."""
    out = {}
    for t in rec.state().trials:
        if t.status == "completed":
            o = {k: v for k, v in rec.outcomes[t.trial_id].items() if k != "attempt"}
            o["reports"] = [
                {k: v for k, v in r.items() if k != "trial_id"} for r in rec.reports if r["trial_id"] == t.trial_id
            ]
            o["samples"] = [(ts, v) for tid, ts, v in rec.sample_rows if tid == t.trial_id]
            out[t.position] = o
    return out


def answers(rec: MemoryRecorder) -> dict:
    return dict(rec.state().answers)


def test_full_run_visits_every_step_in_order_and_records_before_acting():
    rec = MemoryRecorder(toy_plan(), seed=7)
    result = runner(rec).run()
    plan = rec.state().plan
    assert result.status == "completed"
    assert result.steps_done == result.steps_total == len(plan.steps)
    assert result.trials_completed == 4 and result.trials_aborted == 0
    assert result.answers == 3 + 3 + 1
    kinds = [e["kind"] for e in rec.events]
    # every step is entered (committed) before anything happens in it, and done afterwards
    enters = [e["position"] for e in rec.events if e["kind"] == "step_enter"]
    dones = [e["position"] for e in rec.events if e["kind"] == "step_done"]
    assert enters == dones == [s.position for s in plan.steps]
    first_trial = kinds.index("trial_start")
    assert rec.events[first_trial - 1]["kind"] == "step_enter"
    assert kinds[-2:] == ["session_end", "session_status"]
    # the familiarisation of a virtual participant ends early; the break elapses on the simulated clock
    fam = [e for e in rec.events if e["kind"] == "step_done" and e["position"] == 2][0]
    assert fam["payload"]["ended_early"] is True
    brk = [e for e in rec.events if e["kind"] == "step_done" and plan.step(e["position"]).kind == "break"][0]
    assert brk["payload"]["elapsed_s"] == pytest.approx(30.0)
    # scans counted only in the on-request condition A; the device ended safe after each trial
    by_cond = {t.position: t.condition for t in rec.state().trials}
    scans = {by_cond[p]: o["scans"] for p, o in completed_trials(rec).items()}
    assert scans == {"A": 1, "B": 0}
    assert all(d.written[-1] == {"balloon_pct": 0.0} and d.closed == 1 for d in ToyDevice.instances)


def test_the_session_loads_its_plugins_through_the_trial_executor_alone():
    """The runner keeps no second factory: a condition's loop rate (the trial clock's tick) comes from the
    controller the trial executor would build, so a session never times a trial by one factory and builds it
    from another."""

    class Faster(PLUGINS["controller"]["toy_linear"]):
        rate_hz = 125.0

    r = runner(MemoryRecorder(toy_plan(), seed=7))
    assert "factory" not in vars(r)
    conds = r.plan.conditions
    assert (r._rate(conds["A"]), r._rate(conds["B"])) == (50.0, 50.0)
    r.trials.factory = MappingFactory({**PLUGINS, "controller": {"toy_linear": Faster}})
    assert (r._rate(conds["A"]), r._rate(conds["B"])) == (125.0, 50.0)


def test_reports_validated_and_stored_with_time():
    rec = MemoryRecorder(toy_plan(), seed=3)
    runner(rec).run()
    assert rec.reports, "the toy participant reports stiff cells"
    for r in rec.reports:
        assert r["column"] in {"1", "2", "3"} and r["row"] in {"1", "2", "3"} and r["t"] >= 0


def test_same_seed_same_session_other_seed_differs():
    a, b, c = (MemoryRecorder(toy_plan(), seed=s) for s in (11, 11, 12))
    for rec in (a, b, c):
        runner(rec).run()
    assert completed_trials(a) == completed_trials(b)
    assert answers(a) == answers(b)
    assert completed_trials(a) != completed_trials(c)


def test_hard_time_limit_stops_the_trial():
    class Lingerer(ToyParticipant):
        def begin_trial(self, info, rng):
            super().begin_trial(info, rng)
            self.finish_t = 1e9

    rec = MemoryRecorder(toy_plan(time_limit=3.0), seed=1)
    runner(rec, participant=Lingerer()).run()
    outs = completed_trials(rec)
    assert all(o["ended_by"] == "time_limit" and o["timed_out"] for o in outs.values())
    assert all(o["duration_s"] == pytest.approx(3.0) and o["ticks"] == 150 for o in outs.values())


def test_crash_in_trial_then_resume_repeats_it_identically():
    ref = MemoryRecorder(toy_plan(), seed=5)
    runner(ref).run()

    rec = MemoryRecorder(toy_plan(), seed=5)
    ToyParticipant.crash_at = (3, 1.0)
    with pytest.raises(Crash):
        runner(rec).run()
    running = [t for t in rec.state().trials if t.status == "running"]
    assert len(running) == 1 and ToyDevice.instances[-1].written[-1] == {"balloon_pct": 0.0}
    ToyParticipant.crash_at = None
    result = runner(rec).run()
    assert result.status == "completed" and result.resumes == 1
    assert completed_trials(rec) == completed_trials(ref)  # repeat: same position, same streams
    assert answers(rec) == answers(ref)
    statuses = sorted(t.status for t in rec.state().trials)
    assert statuses == ["aborted"] + ["completed"] * 4
    aborted = [t for t in rec.state().trials if t.status == "aborted"][0]
    assert "interrupted" in aborted.reason
    assert rec.audits[0]["action"] == "session_resumed" and rec.audits[0]["interrupted_trials"] == [aborted.trial_id]


def test_crash_then_invalidate_and_append_policy():
    ref = MemoryRecorder(toy_plan("invalidate_and_append"), seed=5)
    runner(ref).run()
    rec = MemoryRecorder(toy_plan("invalidate_and_append"), seed=5)
    ToyParticipant.crash_at = (2, 0.5)
    with pytest.raises(Crash):
        runner(rec).run()
    ToyParticipant.crash_at = None
    runner(rec).run()
    plan = rec.state().plan
    replacement = [s for s in plan.steps if s.replaces is not None]
    assert len(replacement) == 1 and replacement[0].replaces == 5 and replacement[0].condition == "A"
    # the replacement sits after the last trial of block 1, before its questionnaire
    order = [s.position for s in plan.steps]
    assert order.index(replacement[0].position) == order.index(5) + 1
    got, want = completed_trials(rec), completed_trials(ref)
    assert set(got) == (set(want) - {5}) | {replacement[0].position}
    assert {p: got[p] for p in want if p != 5} == {p: want[p] for p in want if p != 5}
    invalid = [t for t in rec.state().trials if t.status == "invalid"]
    assert [t.position for t in invalid] == [5]
    assert answers(rec) == answers(ref)


def test_crash_in_questionnaire_keeps_given_answers():
    ref = MemoryRecorder(toy_plan(), seed=9)
    runner(ref).run()
    rec = MemoryRecorder(toy_plan(), seed=9)
    participant = ToyParticipant()
    asked: list[str] = []
    base = VirtualUI(participant, lambda pos, n: answer_rng(9, pos, n))

    class CrashingUI(VirtualUI):
        def ask_item(self, instrument, item, number, context):
            asked.append(item.id)
            if item.id == "q2" and len(asked) == 2:
                raise Crash()
            return base.ask_item(instrument, item, number, context)

    with pytest.raises(Crash):
        runner(rec, ui=CrashingUI(participant, base.rng_for), participant=participant).run()
    assert list(rec.state().answers) == [(6, "q1")]
    asked.clear()
    runner(rec).run()
    assert answers(rec) == answers(ref)
    assert completed_trials(rec) == completed_trials(ref)
    assert len(rec.responses) == len(ref.responses)  # no answer given twice


def test_ctrl_c_is_a_safe_resumable_stop():
    rec = MemoryRecorder(toy_plan(), seed=2)
    ToyParticipant.interrupt_at = (1, 2.0)
    with pytest.raises(SessionInterrupted, match="studyctl resume 1"):
        runner(rec).run()
    assert rec.state().status == "interrupted"
    aborted = [t for t in rec.state().trials if t.status == "aborted"]
    assert len(aborted) == 1 and aborted[0].reason == "stopped by Ctrl-C"
    assert ToyDevice.instances[-1].written[-1] == {"balloon_pct": 0.0}
    ToyParticipant.interrupt_at = None
    assert runner(rec).run().status == "completed"


def test_device_disconnect_marks_trial_and_session_resumes():
    rec = MemoryRecorder(toy_plan(), seed=4)
    ToyDevice.disconnect_at = 1.0
    with pytest.raises(SessionError, match="device fault: .*USB link lost"):
        runner(rec).run()
    dev = ToyDevice.instances[-1]
    assert dev.closed == 1 and dev.written[-1] == {"balloon_pct": 0.0}
    state = rec.state()
    assert state.status == "interrupted"
    assert [t.status for t in state.trials] == ["aborted"]
    assert state.trials[0].reason.startswith("device fault")
    ToyDevice.disconnect_at = None
    assert runner(rec).run().trials_completed == 4


def test_completed_session_refuses_to_run_again():
    rec = MemoryRecorder(toy_plan(), seed=1)
    runner(rec).run()
    with pytest.raises(SessionError, match="already complete"):
        runner(rec).run()


def test_coordinator_abort_and_mark_invalid_from_script():
    script = Script.from_mapping({
        "default_likert": 3,
        "controls": [
            {"trial": 1, "t": 1.0, "action": "abort", "reason": "probe slipped"},
            {"trial": 3, "t": 0.5, "action": "invalid", "reason": "participant looked"},
        ],
    })
    rec = MemoryRecorder(toy_plan(), seed=8)
    runner(rec, ui=ScriptedUI(script)).run()
    trials = rec.state().trials
    first = [t for t in trials if t.position == 3]
    assert [t.status for t in first] == ["aborted", "completed"]
    assert "probe slipped" in first[0].reason
    third = [t for t in trials if t.position == 8]
    assert [t.status for t in third] == ["invalid"] and third[0].reason == "participant looked"
    assert {a["action"] for a in rec.audits} >= {"trial_aborted", "trial_marked_invalid"}


def test_scripted_invalid_likert_answers_are_reasked_with_reason():
    messages: list[str] = []
    script = Script.from_mapping({"likert": {"q1": ["seven", 9, 4]}, "default_likert": 2})
    ui = ScriptedUI(script, log=messages.append)
    rec = MemoryRecorder(toy_plan(), seed=8)
    runner(rec, ui=ui).run()
    assert rec.state().answers[(6, "q1")] == 4
    assert messages[0] == "item q1: 'seven' is not a number; type one of 1, 2, 3, 4, 5; asking again"
    assert messages[1] == "item q1: 9 is not on the scale; type one of 1, 2, 3, 4, 5; asking again"


def test_condition_checkpoint_refamiliarises_on_resume():
    rec = MemoryRecorder(toy_plan(checkpoint="condition"), seed=5)
    ToyParticipant.crash_at = (4, 1.0)
    with pytest.raises(Crash):
        runner(rec).run()
    ToyParticipant.crash_at = None
    runner(rec).run()
    refresh = [e for e in rec.events if e["kind"] == "checkpoint_refresh"]
    assert len(refresh) == 1 and refresh[0]["payload"]["familiarisation"] == 7


def test_plan_round_trips_through_json():
    import json

    plan = toy_plan("invalidate_and_append")
    again = SessionPlan.from_json(json.loads(json.dumps(plan.to_json())))
    assert again.to_json() == plan.to_json() and again.steps[2].data["placement"]["sites"][0] == [1, 1]


def test_trial_streams_depend_only_on_seed_and_position():
    from studyctl.engine.seeding import trial_streams

    a = trial_streams(1, 5).participant.random(3)
    b = trial_streams(1, 5).participant.random(3)
    c = trial_streams(1, 6).participant.random(3)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_coordinator_pause_stops_the_trial_and_repeats_it():
    script = Script.from_mapping({"default_likert": 3,
                                  "controls": [{"trial": 2, "t": 2.0, "action": "pause", "reason": "phone call"}]})
    rec = MemoryRecorder(toy_plan(), seed=8)
    runner(rec, ui=ScriptedUI(script)).run()
    second = [t for t in rec.state().trials if t.position == 5]
    assert [t.status for t in second] == ["aborted", "completed"]
    assert second[0].reason == "paused by the coordinator: phone call"
    statuses = [e["payload"]["status"] for e in rec.events if e["kind"] == "session_status"]
    assert statuses == ["running", "paused", "running", "completed"]
