"""The repository API on SQLite and PostgreSQL: what goes in comes out, verbatim; bad input is refused."""

from __future__ import annotations

import hashlib
import itertools
from datetime import UTC, datetime

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sqlalchemy import func, select

from studyctl.errors import NotFoundError, UsageError
from studyctl.store.models import Participant

_names = itertools.count()

NASTY_CODES = [
    "P'01",
    'P"02',
    "P03'); DROP TABLE participant; --",
    "P04\\n\\x00literal",
    "P05\ttab\nnewline\rcr",
    "P06 \x1b[31mred\x1b[0m \x07bell",
    "P07 [bold]markup[/bold] %s %(x)s {0}",
    "P08 ünïcödé 参加者 🧪",
    " P09 leading and trailing spaces ",
    "P10 --",
    "P11 ;",
    "P12 $$ dollar-quoted $$",
]


def test_study_round_trip(store):
    text = "studyctl_protocol: 1\nstudy: {id: demo}\n"
    study = store.create_study("demo", protocol_text=text, protocol_name="demo", seed=123)
    again = store.get_study("demo")
    assert again.id == study.id
    assert again.protocol_text == text
    assert again.protocol_sha256 == hashlib.sha256(text.encode()).hexdigest()
    assert again.seed == 123
    assert again.created_at.tzinfo is not None
    assert store.get_study().name == "demo"  # the only study
    with pytest.raises(UsageError, match="already holds a study named 'demo'"):
        store.create_study("demo")


def test_get_study_without_name_needs_exactly_one(store):
    with pytest.raises(NotFoundError, match="no study yet"):
        store.get_study()
    store.create_study("a")
    store.create_study("b")
    with pytest.raises(UsageError, match="several studies"):
        store.get_study()
    with pytest.raises(NotFoundError, match="studies: 'a', 'b'"):
        store.get_study("c")


def test_random_seed_is_stored_and_in_range(store):
    study = store.create_study("s")
    assert 0 <= study.seed < 2**63
    with pytest.raises(UsageError, match="seed"):
        store.create_study("t", seed=-1)
    with pytest.raises(UsageError, match="seed"):
        store.create_study("t", seed=2**63)


@pytest.mark.parametrize("code", NASTY_CODES, ids=range(len(NASTY_CODES)))
@pytest.mark.slow
def test_codes_are_stored_verbatim(store, code):
    study = store.create_study("s")
    schedule = [{"position": 0, "condition": code, "note": code}]
    p = store.add_participant(study.id, code, stratum=code[:50], group="novice", schedule=schedule)
    got = store.get_participant(study.id, code)
    assert got.id == p.id and got.code == code and got.stratum == code[:50]
    assert got.schedule == schedule
    # The table is intact and holds exactly one row.
    with store.reading() as s:
        assert s.scalar(select(func.count()).select_from(Participant)) == 1
    assert [x.code for x in store.list_participants(study.id)] == [code]
    assert store.verify_audit().ok


def test_similar_codes_are_distinct(store):
    study = store.create_study("s")
    for code in ["p1", "P1", "P1 ", "P1\n"]:
        store.add_participant(study.id, code)
    assert sorted(p.code for p in store.list_participants(study.id)) == sorted(["p1", "P1", "P1 ", "P1\n"])
    with pytest.raises(UsageError, match="already enrolled"):
        store.add_participant(study.id, "P1")


@pytest.mark.parametrize(
    ("code", "match"),
    [("", "must not be empty"), ("x" * 201, "at most 200"), ("a\x00b", "NUL"), (5, "must be text")],
)
def test_bad_codes_are_refused(store, code, match):
    study = store.create_study("s")
    with pytest.raises(UsageError, match=match):
        store.add_participant(study.id, code)


def test_status_values_are_checked(store):
    study = store.create_study("s")
    with pytest.raises(UsageError, match="participant status 'gone' is not allowed; use one of enrolled"):
        store.add_participant(study.id, "P1", status="gone")
    p = store.add_participant(study.id, "P1")
    with pytest.raises(UsageError, match="trial status"):
        sess = store.start_session(p.id)
        store.add_trial(sess.id, plan_position=0, condition="a", status="done")
    with pytest.raises(UsageError, match="cannot update trial field"):
        t = store.add_trial(sess.id, plan_position=0, condition="a")
        store.update_trial(t.id, condition="b")


def test_session_trial_lifecycle(store):
    study = store.create_study("s")
    p = store.add_participant(study.id, "P1", sequence_slot=3, schedule=[{"c": "x"}], schedule_seed=9,
                              schedule_algorithm_version="v1")
    assert p.schedule_sha256 is not None
    sess = store.start_session(p.id, seed=77, site="lab-a")
    t1 = store.add_trial(sess.id, plan_position=0, condition="linear", block=1, repetition=1,
                         placement={"holes": [1, 4, 6]}, time_limit_s=90.0)
    store.update_trial(t1.id, status="running", started_at=datetime.now(UTC))
    store.update_trial(t1.id, status="invalid", invalid_reason="sensor unplugged 'A'", ended_at=datetime.now(UTC))
    t2 = store.add_trial(sess.id, plan_position=0, condition="linear", block=1, repetition=1,
                         placement={"holes": [1, 4, 6]}, replaces_trial_id=t1.id)
    store.update_trial(t2.id, status="completed", timed_out=True, outcome={"found": 2, "scans": 5})
    store.update_session(sess.id, status="completed", ended_at=datetime.now(UTC))
    trials = store.list_trials(participant_id=p.id)
    assert [(t.id, t.status, t.replaces_trial_id) for t in trials] == [
        (t1.id, "invalid", None), (t2.id, "completed", t1.id)]
    assert trials[1].timed_out is True and trials[1].outcome == {"found": 2, "scans": 5}
    assert store.get_session(sess.id).status == "completed"
    every = list(store.audit_frame()["action"])
    # records written through the store API are sealed in their own transaction (records.seal rows between)
    assert every.count("records.seal") == 5
    actions = [a for a in every if a != "records.seal"]
    assert actions == ["study.create", "participant.enroll", "session.start", "trial.status", "trial.status",
                       "trial.replace", "trial.status", "session.update"]
    with pytest.raises(NotFoundError):
        store.add_trial(sess.id, plan_position=1, condition="x", replaces_trial_id=999_999)


def test_events_are_numbered_per_session(store):
    study = store.create_study("s")
    p = store.add_participant(study.id, "P1")
    a, b = store.start_session(p.id), store.start_session(p.id)
    trial = store.add_trial(a.id, plan_position=0, condition="c")
    assert store.append_event(a.id, "start", {"x": "it's"}, t_mono=0.5, trial_id=trial.id) == 1
    assert store.append_events(a.id, [(0.6, "scan", {"n": 1}), (0.7, "scan", None)], trial_id=trial.id) == [2, 3]
    assert store.append_event(b.id, "start", t_mono=0.1) == 1
    frame = store.events_frame(a.id)
    assert list(frame.columns) == ["seq", "trial_id", "t_mono", "t_wall", "kind", "payload"]
    assert list(frame["seq"]) == [1, 2, 3] and list(frame["kind"]) == ["start", "scan", "scan"]
    assert frame["payload"][0] == {"x": "it's"}


def test_responses_and_reports(store):
    study = store.create_study("s")
    p = store.add_participant(study.id, "P1")
    sess = store.start_session(p.id)
    trial = store.add_trial(sess.id, plan_position=0, condition="c")
    store.record_response(p.id, session_id=sess.id, trial_id=trial.id, instrument="usefulness",
                          instrument_version="1.0", item="Q1 'quoted'", code=4, context="after ES")
    with pytest.raises(UsageError, match="integer"):
        store.record_response(p.id, instrument="u", instrument_version="1", item="Q", code="4")
    frame = store.responses_frame(p.id)
    assert frame.loc[0, "item"] == "Q1 'quoted'" and frame.loc[0, "code"] == 4
    store.record_location_report(trial.id, t=12.5, payload={"cell": [2, 3]}, correct=True)
    store.record_location_report(trial.id, t=13.0, payload={"cell": [0, 0]})
    reports = store.location_reports(trial.id)
    assert [(r.payload, r.correct) for r in reports] == [({"cell": [2, 3]}, True), ({"cell": [0, 0]}, None)]


def test_transaction_groups_changes_and_rolls_back(store):
    study = store.create_study("s")
    with pytest.raises(RuntimeError), store.in_transaction(lock="enroll") as tx:
        store.add_participant(study.id, "P1", tx=tx)
        store.add_participant(study.id, "P2", tx=tx)
        raise RuntimeError("boom")
    assert store.list_participants(study.id) == []
    with store.in_transaction(lock="enroll") as tx:
        store.add_participant(study.id, "P1", tx=tx)
        store.add_participant(study.id, "P2", tx=tx)
    assert [p.code for p in store.list_participants(study.id)] == ["P1", "P2"]
    assert store.verify_audit().ok and store.verify_audit().rows == 3


def test_naive_datetimes_are_refused(store):
    study = store.create_study("s")
    p = store.add_participant(study.id, "P1")
    sess = store.start_session(p.id)
    trial = store.add_trial(sess.id, plan_position=0, condition="c")
    with pytest.raises(Exception, match="naive datetime"):
        store.update_trial(trial.id, started_at=datetime(2024, 1, 1))


def test_withdrawal_records_reason(store):
    study = store.create_study("s")
    p = store.add_participant(study.id, "P1")
    store.set_participant_status(p.id, "withdrawn", reason="felt unwell")
    got = store.get_participant(study.id, "P1")
    assert got.status == "withdrawn" and got.withdrawal_reason == "felt unwell" and got.withdrawn_at is not None


def test_lone_surrogates_are_refused(store):
    study = store.create_study("s")
    with pytest.raises(UsageError, match="not valid Unicode"):
        store.add_participant(study.id, "P\udc80")


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(codes=st.lists(
    st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), min_size=1, max_size=60),
    min_size=1, max_size=4, unique=True))
@pytest.mark.slow
def test_any_text_code_round_trips(store, codes):
    study = store.create_study(f"s{next(_names)}")
    for code in codes:
        store.add_participant(study.id, code)
    assert sorted(p.code for p in store.list_participants(study.id)) == sorted(codes)
    for code in codes:
        assert store.get_participant(study.id, code).code == code


def test_forgotten_tx_is_an_immediate_error_not_a_deadlock(store):
    study = store.create_study("s")
    with pytest.raises(UsageError, match="pass its session as tx="), store.in_transaction() as tx:
        store.add_participant(study.id, "P1", tx=tx)
        store.add_participant(study.id, "P2")  # forgot tx=: would wait for the outer transaction
    assert store.list_participants(study.id) == []  # the outer transaction rolled back
    with store.in_transaction() as tx:  # and the store is usable again
        store.add_participant(study.id, "P3", tx=tx)
    assert [p.code for p in store.list_participants(study.id)] == ["P3"]
