"""Every trial stores its scene's hidden truth; analysis scores against it without rebuilding the scene."""

from __future__ import annotations

import json

import pytest
from sqlalchemy import select

from studyctl.analysis import analyze, load_plan
from studyctl.analysis.truth import SceneTruth
from studyctl.engine.plan import SessionPlan
from studyctl.store.models import Event, Session, Trial
from studyctl.store.workspace import open_study
from studyctl.workflows.simulate import simulate_study


@pytest.mark.parametrize(
    ("protocol", "rate"),
    [("bio_inspired_palpation", None), ("needle_insertion", None), ("data_driven_palpation", 250.0)],
)
@pytest.mark.slow
def test_stored_truth_is_the_scene_truth_and_analysis_uses_it(tmp_path, monkeypatch, protocol, rate):
    simulate_study(protocol, 1, 4, tmp_path / "ws", sim_rate_hz=rate)
    with open_study(workspace=tmp_path / "ws") as opened, opened.store.reading() as s:
        sess = s.scalars(select(Session)).one()
        plan = SessionPlan.from_json(
            s.scalar(select(Event.payload).where(Event.kind == "session_plan"))["plan"]
        )
        trials = list(s.scalars(select(Trial).where(Trial.status == "completed")))
        stored = dict(s.execute(select(Event.trial_id, Event.payload).where(Event.kind == "scene_truth")).all())
    scored = [tr for tr in trials if not plan.conditions[tr.condition].manual or tr.id in stored]
    assert scored and all(tr.id in stored for tr in scored)
    truths = SceneTruth()
    for tr in scored:
        rebuilt = truths.rebuild(plan, tr.placement or {}, int(sess.seed), int(tr.plan_position))
        assert stored[tr.id] == json.loads(json.dumps(rebuilt))  # what older databases get by rebuilding

    def no_rebuild(*_args, **_kwargs):
        raise AssertionError("analysis rebuilt a scene although the trial stored its truth")

    monkeypatch.setattr(SceneTruth, "rebuild", no_rebuild)
    result = analyze(load_plan(protocol), workspace=tmp_path / "ws")
    assert len(result.data.frame) and result.data.missing.empty
