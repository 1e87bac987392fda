"""StudyReader: one study's trials, events, reports, samples and answers as typed rows, read once."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from studyctl.store.reader import StudyReader


def _fill(store, name: str, *, seed: int = 11):
    """A study with two participants, an amended plan, a repeated (aborted then completed) step and answers."""
    study = store.create_study(name, protocol_name="p", seed=seed)
    a = store.add_participant(study.id, "A", group="novice")
    b = store.add_participant(study.id, "B", stratum="expert")
    sa = store.start_session(a.id, seed=101)
    sb = store.start_session(b.id, seed=None)
    store.append_event(sa.id, "session_plan", {"plan": {"version": 1, "tag": "first"}}, t_mono=0.0)
    store.append_event(sa.id, "plan_amended", {"plan": {"version": 1, "tag": "amended"}}, t_mono=0.5)
    t1 = store.add_trial(sa.id, plan_position=0, condition="x", repetition=1, placement={"hole": 3}, status="aborted")
    store.update_trial(t1.id, invalid_reason="probe slipped")
    t2 = store.add_trial(sa.id, plan_position=1, condition="x", repetition=1, time_limit_s=60.0, status="completed")
    store.update_trial(t2.id, outcome={"step": 0, "duration_s": 12.5})
    t3 = store.add_trial(sb.id, plan_position=0, condition="y", status="completed")
    store.append_event(sa.id, "scene_truth", {"tumours": [{"col": 1}]}, t_mono=1.0, trial_id=t2.id)
    store.append_event(sa.id, "scan", None, t_mono=2.0, trial_id=t2.id)
    store.append_event(sa.id, "not_for_trials", {"x": 1}, t_mono=2.5)  # a session event without a trial: not read
    store.record_location_report(t2.id, t=3.0, payload={"column": "B", "row": "2"})
    store.record_location_report(t2.id, t=4.0, payload={"column": "C", "row": "1"})
    with store.sample_writer(t2.id, ["force_n"]) as w:
        w.append_block(np.arange(5) / 50.0, np.arange(5.0).reshape(-1, 1))
    store.record_response(a.id, instrument="q", instrument_version="1", item="i1", code=4, session_id=sa.id,
                          context="step:0")
    store.record_response(b.id, instrument="q", instrument_version="1", item="i1", code=2)
    return study, (a, b), (sa, sb), (t1, t2, t3)


@pytest.mark.slow
def test_reader_gives_typed_rows_of_one_study(store):
    study, (a, b), (sa, sb), (t1, t2, t3) = _fill(store, "one")
    _fill(store, "other", seed=12)  # a second study in the same database stays out of every answer
    reader = StudyReader(store, "one")
    assert reader.study.name == "one" and reader.study.seed == 11
    assert [p.code for p in reader.participants] == ["A", "B"]
    assert [p.group for p in reader.participants] == ["novice", "expert"]  # group, else stratum
    sess = {s.id: s for s in reader.sessions}
    assert sess[sa.id].plan_json == {"version": 1, "tag": "amended"}  # the last (amended) plan
    assert sess[sb.id].plan_json is None and sess[sb.id].seed == 0
    trials = {t.id: t for t in reader.trials}
    assert list(trials) == [t1.id, t2.id, t3.id]
    assert trials[t1.id].status == "aborted" and trials[t1.id].invalid_reason == "probe slipped"
    assert trials[t1.id].placement == {"hole": 3} and trials[t1.id].step == 0
    done = trials[t2.id]
    assert done.step == 0  # the outcome's step: it repeats the aborted attempt at plan step 0
    assert done.outcome["duration_s"] == 12.5 and done.time_limit_s == 60.0
    assert [(e.kind, e.t) for e in done.events] == [("scene_truth", 1.0), ("scan", 2.0)]
    assert done.stored_truth == {"tumours": [{"col": 1}]}
    assert trials[t3.id].stored_truth is None
    assert [(r.t, dict(r.payload)) for r in done.reports] == [
        (3.0, {"column": "B", "row": "2"}),
        (4.0, {"column": "C", "row": "1"}),
    ]
    with pytest.raises(dataclasses.FrozenInstanceError):
        done.status = "planned"  # type: ignore[misc]
    with pytest.raises(TypeError):
        done.outcome["step"] = 3  # type: ignore[index]
    assert reader.first_completed(["x", "y", "z"]) == {"x": done, "y": trials[t3.id]}
    samples = reader.samples(t2.id)
    assert list(samples.columns) == ["t", "force_n"] and samples["force_n"].tolist() == [0, 1, 2, 3, 4]
    answers = reader.answers()
    assert answers["participant_id"].tolist() == [a.id, b.id]
    assert answers["context"].iloc[0] == "step:0" and answers["context"].isna().iloc[1]
    assert reader.source.endswith("(study 'one')")


def test_the_snapshot_is_read_once(store):
    _fill(store, "one")
    reader = StudyReader(store, "one")
    first = reader.snapshot
    store.add_participant(reader.study.id, "late")
    assert reader.snapshot is first and len(reader.participants) == 2  # one consistent snapshot per reader
    assert len(StudyReader(store, "one").participants) == 3


def test_open_closes_only_what_it_opened(tmp_path):
    from studyctl.store import StudyStore

    url = f"sqlite:///{tmp_path / 'study.db'}"
    store = StudyStore.create(url)
    _fill(store, "one")
    with StudyReader(store) as reader:  # the only study
        assert reader.study.name == "one"
    assert store.get_study("one").name == "one"  # still open: the reader did not own it
    store.close()
    with StudyReader.open(db=url) as reader:
        assert len(reader.trials) == 3


def test_rows_follow_participants_not_the_order_workers_wrote_them(store):
    """Two workers: the second participant's session, trials and answers reach the database first."""
    study = store.create_study("race", protocol_name="p", seed=1)
    a = store.add_participant(study.id, "A")
    b = store.add_participant(study.id, "B")
    sb = store.start_session(b.id, seed=2)
    tb = store.add_trial(sb.id, plan_position=0, condition="x", status="completed")
    store.record_response(b.id, instrument="q", instrument_version="1", item="i1", code=2, session_id=sb.id)
    sa = store.start_session(a.id, seed=1)
    ta0 = store.add_trial(sa.id, plan_position=0, condition="x", status="completed")
    ta1 = store.add_trial(sa.id, plan_position=1, condition="y", status="completed")
    store.record_response(a.id, instrument="q", instrument_version="1", item="i1", code=4, session_id=sa.id)
    reader = StudyReader(store, "race")
    assert [s.id for s in reader.sessions] == [sa.id, sb.id]
    assert [t.id for t in reader.trials] == [ta0.id, ta1.id, tb.id]
    assert reader.answers()["participant_id"].tolist() == [a.id, b.id]


def test_the_roster_is_read_afresh_without_rehearsals_events_or_samples(store):
    """What `studyctl status` (progress, data gaps) reads: rows as they stand now, a rehearsal left out."""
    study, (a, b), (sa, sb), (t1, t2, t3) = _fill(store, "one")
    rehearsal = store.start_session(b.id, seed=3)
    store.append_event(rehearsal.id, "session_plan", {"plan": {"version": 1}, "rehearsal": True}, t_mono=0.0)
    tr = store.add_trial(rehearsal.id, plan_position=0, condition="y", status="completed")
    store.record_response(b.id, instrument="q", instrument_version="1", item="i2", code=1, session_id=rehearsal.id)
    reader = StudyReader(store, "one")
    roster = reader.roster()
    assert [x.id for x in roster.sessions] == [sa.id, sb.id]
    assert [t.id for t in roster.trials] == [t1.id, t2.id, t3.id]
    assert [t.plan_position for t in roster.trials] == [0, 1, 0] and [t.step for t in roster.trials] == [0, 0, 0]
    assert all(t.events == () for t in roster.trials) and all(x.plan_json is None for x in roster.sessions)
    assert reader.stored_sample_rows([t1.id, t2.id, tr.id]) == {t2.id: 5}
    assert [(r.participant_id, r.item, r.code) for r in reader.answer_rows()] == [(a.id, "i1", 4), (b.id, "i1", 2)]
    store.update_trial(t3.id, status="invalid")
    assert [t.status for t in reader.roster().trials][-1] == "invalid"  # afresh, unlike the snapshot
