"""A virtual participant resumed in a new process answers its questionnaires exactly as in an uninterrupted run.

The answers of the built-in virtual participants must come from the stored trial record the engine passes with
each item, not from memory that dies with the process:

* seed 001 (needle operator): a real ``studyctl run`` is SIGKILLed in the middle of a scenario questionnaire
  (the helpers of ``test_kill_resume``) and ``studyctl resume``d; answers, and the trial run after the resume
  (the operator's traits come from the session seed, not from the first trial it happens to see), match an
  uninterrupted run of the same seed.
* seed 003 (tissue palpator): the session is stopped as the end-of-study question is asked, then resumed with
  a fresh participant object; the answer matches the uninterrupted run's.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml
from test_kill_resume import CODE, cli, env, run_and_kill, snapshot  # noqa: F401  (env is a fixture)

from studyctl.engine.api import resume_session, run_session
from studyctl.errors import SessionInterrupted
from studyctl.participants.tissue_palpator import VirtualTissuePalpator
from studyctl.resources import find_shipped
from studyctl.store import StudyStore
from studyctl.store.enrollment import enroll
from studyctl.store.workspace import init_workspace, open_study

pytestmark = pytest.mark.slow


def _needle_protocol(folder: Path) -> Path:
    """Seed 001's shipped protocol cut to one trial each of BL, ES and RT, with a questionnaire after ES and RT
    and at the end (the participant code prefix of ``test_kill_resume``)."""
    doc = yaml.safe_load(find_shipped("protocols", "needle_insertion").read_text())
    doc["conditions"] = [c for c in doc["conditions"] if c["id"] in ("BL", "ES", "RT")]
    doc["counterbalance"] = {"scheme": "explicit", "fixed_first": ["BL"], "orders": [["ES", "RT"]]}
    doc["design"]["repetitions"] = 1
    doc["participants"] = {**doc["participants"], "code_prefix": CODE.split("-")[0], "target_n": 1,
                           "strata": [{"id": "all", "label": "all", "target_n": 1}]}
    doc["trial"]["familiarisation"]["max_s"] = 5
    doc["questionnaires"][0]["conditions"] = ["ES", "RT"]
    path = folder / "needle_resume.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def needle_workspaces(env, tmp_path_factory):  # noqa: F811
    root = tmp_path_factory.mktemp("needle_resume")
    protocol = _needle_protocol(root)
    script = textwrap.dedent(f'''
        import sys
        from studyctl.store.workspace import init_workspace, open_study
        from studyctl.store.enrollment import enroll
        for ws in sys.argv[1:]:
            init_workspace(ws, protocol={str(protocol)!r})
            with open_study(workspace=ws) as o:
                enroll(o.store, code={CODE!r})
    ''')
    paths = {n: root / n for n in ("reference", "killed")}
    subprocess.run([sys.executable, "-c", script, *map(str, paths.values())], env=env, check=True, timeout=300)
    return paths


def test_needle_operator_killed_in_a_questionnaire_answers_as_if_uninterrupted(needle_workspaces, env):  # noqa: F811
    ref_ws, ws = needle_workspaces["reference"], needle_workspaces["killed"]
    cli(["run", "--participant", CODE, "--virtual", "--seed", "5"], ref_ws, env)
    reference = snapshot(ref_ws)
    assert reference["session_status"] == "completed" and len(reference["trials"]) == 3
    assert len(reference["answers"]) == 9  # 3 items after ES, 3 after RT, 3 at the end

    position, _ = run_and_kill(ws, env, "questionnaire")
    before = snapshot(ws)
    kept = {k: v for k, v in before["answers"].items() if k[0] == f"step:{position}"}
    assert 0 < len(kept) < 3 and len(before["trials"]) == 2  # killed after ES, before RT
    cli(["resume", "1", "--take-over"], ws, env)  # the killed process's lease is taken over explicitly
    after = snapshot(ws)
    assert after["session_status"] == "completed" and after["resumes"] == 1
    assert after["answers"] == reference["answers"]
    # the RT trial ran in the resumed process: the same person (traits) on the same streams
    assert after["trials"] == reference["trials"]


def _seed003_protocol(folder: Path) -> Path:
    """Seed 003's shipped protocol with a quicker virtual participant (a coarser survey)."""
    doc = yaml.safe_load(find_shipped("protocols", "pseudo_haptic_palpation").read_text())
    doc["participants"]["virtual"]["params"] = {"line_spacing_mm": 16.0, "press_spacing_mm": 16.0,
                                                "follow_up_count": 3}
    path = folder / "php_quick.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _stop_at_questionnaire(participant, ui, recorder):
    """Front end that stops the session (Ctrl-C) when the first questionnaire item is asked."""

    class Stopping:
        def __getattr__(self, name):
            return getattr(ui, name)

        def ask_item(self, *args, **kwargs):
            raise KeyboardInterrupt

    return participant, Stopping()


def _answers(store: StudyStore) -> dict[tuple[str, str], int]:
    frame = store.responses_frame()
    return {(c, i): int(code) for c, i, code in zip(frame.context, frame.item, frame.code, strict=True)}


def test_tissue_palpator_resumed_at_the_end_question_answers_as_if_uninterrupted(tmp_path):
    protocol = _seed003_protocol(tmp_path)
    results = {}
    for name in ("reference", "stopped"):
        folder = tmp_path / name
        init_workspace(folder, protocol=protocol)
        with open_study(workspace=folder) as o:
            code = enroll(o.store, code="PHP-VVVVV").code
            if name == "reference":
                assert run_session(o.store, code, virtual=True, seed=3).status == "completed"
            else:
                with pytest.raises(SessionInterrupted):
                    run_session(o.store, code, virtual=True, seed=3, frontend=_stop_at_questionnaire)
                assert _answers(o.store) == {}
                sid = o.store.list_trials()[0].session_id
                # a new participant object, as in a new process: it remembers nothing of the four trials
                fresh = VirtualTissuePalpator({"line_spacing_mm": 16.0, "press_spacing_mm": 16.0,
                                               "follow_up_count": 3})
                assert resume_session(o.store, sid, participant=fresh).status == "completed"
                assert fresh.experience == []
            results[name] = (_answers(o.store), sorted((t.plan_position, t.condition, t.outcome.get("duration_s"),
                                                        t.outcome.get("reports")) for t in o.store.list_trials()))
    assert results["stopped"] == results["reference"]
    assert len(results["reference"][0]) == 1
