"""The store-backed recorder: same engine, data in the study database, state rebuilt after a crash."""

from __future__ import annotations

import pytest
from engine_toys import PLUGINS, Crash, ToyParticipant, reset_toys, toy_plan

from studyctl.engine.clock import SimulatedClock
from studyctl.engine.factory import MappingFactory
from studyctl.engine.seeding import answer_rng
from studyctl.engine.session import SessionRunner
from studyctl.engine.store_recorder import StoreRecorder
from studyctl.engine.ui import VirtualUI
from studyctl.store import StudyStore


@pytest.fixture(autouse=True)
def _reset():
    reset_toys()
    yield
    reset_toys()


@pytest.fixture
def store(tmp_path):
    s = StudyStore.create(tmp_path / "study.db")
    yield s
    s.close()


def _participant(store, code="P001"):
    study = store.create_study(f"toy-{code}", protocol_text=None, seed=1)
    return store.add_participant(study.id, code)


def _run(rec):
    p = ToyParticipant()
    seed = rec.state().seed
    ui = VirtualUI(p, lambda pos, n: answer_rng(seed, pos, n))
    return SessionRunner(rec, ui=ui, participant=p, clock=SimulatedClock(), factory=MappingFactory(PLUGINS),
                         virtual=True).run()


def _snapshot(store, session_id):
    trials = [t for t in store.list_trials(session_id=session_id) if t.status == "completed"]
    out = {}
    for t in trials:
        samples = store.read_samples(t.id)
        reports = [(r.t, r.payload) for r in store.location_reports(t.id)]
        o = {k: v for k, v in t.outcome.items() if k != "attempt"}
        out[t.outcome["step"]] = (t.condition, t.plan_position, o, reports, samples.round(12).to_dict("list"))
    resp = store.responses_frame()
    resp = resp[resp.session_id == session_id]
    answers = sorted(zip(resp.context, resp.item, resp.code, strict=True))
    return out, answers


@pytest.mark.slow
def test_store_run_writes_everything_and_reloads(store):
    p = _participant(store)
    rec = StoreRecorder.create(store, p.id, toy_plan(), seed=21, virtual=True)
    result = _run(rec)
    assert result.status == "completed" and result.trials_completed == 4
    sess = store.get_session(rec.session_id)
    assert sess.status == "completed" and sess.ended_at is not None
    assert store.get_participant(p.study_id, "P001").status == "completed"
    trials = store.list_trials(session_id=rec.session_id)
    assert [t.status for t in trials] == ["completed"] * 4
    assert [t.plan_position for t in trials] == [1, 2, 3, 4]
    samples = store.read_samples(trials[0].id)
    assert len(samples) == trials[0].outcome["ticks"] and {"force_n", "balloon_pct"} <= set(samples.columns)
    events = store.events_frame(rec.session_id)
    assert events.kind.iloc[0] == "session_plan" and events.kind.iloc[-1] == "session_status"
    assert (events.kind == "scan").sum() == 2
    again = StoreRecorder.load(store, rec.session_id).state()
    assert again.status == "completed" and again.completed == set(range(1, 14))
    assert len(again.answers) == 7
    assert store.verify_audit().ok


@pytest.mark.parametrize("policy", ["repeat", "invalidate_and_append"])
@pytest.mark.slow
def test_crash_mid_trial_resume_from_database(store, policy):
    ref_p = _participant(store, "REF")
    ref = StoreRecorder.create(store, ref_p.id, toy_plan(policy), seed=5, virtual=True)
    _run(ref)

    p = _participant(store, "P002")
    rec = StoreRecorder.create(store, p.id, toy_plan(policy), seed=5, virtual=True)
    ToyParticipant.crash_at = (3, 2.0)
    with pytest.raises(Crash):
        _run(rec)
    ToyParticipant.crash_at = None
    loaded = StoreRecorder.load(store, rec.session_id)
    assert [t.status for t in loaded.state().trials if t.position == 8] == ["running"]
    result = _run(loaded)
    assert result.status == "completed" and result.resumes == 1
    got, got_answers = _snapshot(store, rec.session_id)
    want, want_answers = _snapshot(store, ref.session_id)
    assert got_answers == want_answers
    if policy == "repeat":
        assert got == want
        rows = store.list_trials(session_id=rec.session_id)
        repeat = [t for t in rows if t.replaces_trial_id is not None]
        assert len(repeat) == 1 and repeat[0].plan_position == 3
        assert store.get_trial(repeat[0].replaces_trial_id).status == "aborted"
    else:
        assert {k: v for k, v in got.items() if k != 8 and k < 14} == {k: v for k, v in want.items() if k != 8}
        invalid = [t for t in store.list_trials(session_id=rec.session_id) if t.status == "invalid"]
        assert len(invalid) == 1 and invalid[0].outcome["step"] == 8
    audit = store.audit_frame()
    assert (audit.action == "session.session_resumed").sum() == 1
    assert store.verify_audit().ok
