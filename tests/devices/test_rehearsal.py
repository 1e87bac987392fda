"""Rehearsals: a whole session on emulated hardware, scripted, recorded as a rehearsal and never analysed."""

from __future__ import annotations

import socket

import pytest

from studyctl.devices import board_protocol as bp
from studyctl.engine.api import run_session, session_is_rehearsal
from studyctl.engine.trial_loop import TIMING_FAULTS
from studyctl.engine.ui import Script
from studyctl.store.models import Event

pytestmark = pytest.mark.slow


def _script(n_trials: int, finish_s: float = 0.6, **extra) -> Script:
    return Script.from_mapping({
        "default_likert": 3,
        "trials": {i: [{"t": finish_s / 2, "request": "report", "answer": "3 4"}, {"t": finish_s, "request": "finish"}]
                   for i in range(1, n_trials + 1)},
        **extra,
    })


def _events(store, sid):
    with store.reading() as s:
        return [(k, p) for k, p in s.execute(
            Event.__table__.select().with_only_columns(Event.kind, Event.payload).where(Event.session_id == sid)
            .order_by(Event.seq))]


def test_a_whole_rehearsal_session_runs_on_the_board_emulator(study):
    """The issue's fault: a scripted session on the UDP driver board faulted stale_sensor at t = 0.12 s (the
    trial ran on the script's simulated clock against a real-time board). Now every trial completes on the
    emulator, in real time, with no device fault, and the session is a rehearsal."""
    opened, code = study("bio_inspired_palpation", "novice")
    logs: list[str] = []
    result = run_session(opened.store, code, virtual=False, script=_script(4), rehearse=True, log=logs.append)
    assert result.status == "completed" and result.trials_completed == 4 and result.trials_aborted == 0
    events = _events(opened.store, result.session_id)
    kinds = [k for k, _ in events]
    assert "device_fault" not in kinds, [p for k, p in events if k == "device_fault"]
    assert kinds.count("servo_timing") == 4  # every hardware trial ran in the servo process
    loop_ends = [p for k, p in events if k == "trial_loop_end"]
    assert all(p["ended_by"] == "finish" and 25 <= p["ticks"] <= 40 for p in loop_ends), loop_ends  # 0.6 s at 50 Hz
    assert session_is_rehearsal(opened.store, result.session_id)
    # the participant has not taken part: status unchanged, a real session can still follow
    assert opened.store.get_participant(opened.study.id, code).status == "enrolled"
    # the emulator was stopped with the session: nobody answers at its port any more
    port = int(next(m for m in logs if m.startswith("rehearsal:")).split("port=")[1].rstrip(")"))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(0.5)
        s.connect(("127.0.0.1", port))
        s.send(bp.encode(bp.HELLO, 1, 50, 250))
        with pytest.raises((TimeoutError, ConnectionRefusedError)):
            s.recv(2048)


def test_rehearsals_are_left_out_of_analysis(study, capsys):
    from studyctl.store.reader import StudyReader  # noqa: PLC0415

    opened, code = study("bio_inspired_palpation", "novice")
    run_session(opened.store, code, virtual=False, script=_script(4, 0.3), rehearse=True)
    from studyctl.engine.progress import study_progress  # noqa: PLC0415

    reader = StudyReader(opened.store, opened.study)
    assert reader.trials == () and reader.sessions == () and reader.answers().empty
    rows = study_progress(opened.store, opened.study.name).rows
    assert rows and all(r.session_id is None and r.done == 0 for r in rows)  # status: a rehearsal is not progress
    assert len(opened.store.list_sessions(opened.store.get_participant(opened.study.id, code).id)) == 1  # recorded
    # `studyctl status`: the totals are the study's data; the rehearsal is counted apart
    from studyctl.store.status import study_status  # noqa: PLC0415

    info = study_status(opened.store, opened.study)
    assert sum(info.sessions.values()) == 0 and sum(info.trials.values()) == 0, info
    assert info.rehearsal_sessions["completed"] == 1 and info.rehearsal_trials["completed"] == 4, info
    from studyctl.cli.app import main  # noqa: PLC0415

    db = str(opened.store.db.url)
    assert main(["status", "--db", db]) == 0
    out = capsys.readouterr().out
    assert "sessions:     0 (" in out and "trials:       0 (" in out
    assert "rehearsals:   1 sessions, 4 trials (run --rehearse; not counted above, never analysed)" in out, out
    run_session(opened.store, code, virtual=True, seed=3)  # the real session (simulated): counted, not the rehearsal
    info = study_status(opened.store, opened.study)
    assert info.sessions["completed"] == 1 and info.trials["completed"] == 4
    assert info.rehearsal_sessions["completed"] == 1 and info.rehearsal_trials["completed"] == 4


def test_a_virtual_participant_rehearses_on_the_emulated_board(tmp_path):
    """``run --rehearse --virtual``: the protocol's virtual participant acts on the emulated driver board (the
    emulator process, through the servo process and the real UDP adapter) instead of the simulated device. Its hand
    presses the trial's phantom in the emulator's world: the force reaches the controller only through the emulated
    ADC, the packets and the adapter, and the balloon/motor commands go back the same way. Recorded as a rehearsal,
    left out of analysis."""
    from studyctl.engine.progress import study_progress  # noqa: PLC0415
    from studyctl.protocol.loader import resolve_protocol  # noqa: PLC0415
    from studyctl.store.enrollment import enroll, study_protocol  # noqa: PLC0415
    from studyctl.store.reader import StudyReader  # noqa: PLC0415
    from studyctl.store.samples import read_samples  # noqa: PLC0415
    from studyctl.store.workspace import init_workspace, open_study  # noqa: PLC0415

    # the shipped protocol with a 6 s time limit per trial (the palpator then reports its best guesses in time):
    # hardware runs in real time, so a whole unbounded search per trial would take minutes
    text = resolve_protocol("bio_inspired_palpation").read_text().replace("time_limit_s: null", "time_limit_s: 6")
    assert "time_limit_s: 6" in text
    (tmp_path / "bip.yaml").write_text(text)
    init_workspace(tmp_path / "ws", protocol=str(tmp_path / "bip.yaml"))
    with open_study(workspace=tmp_path / "ws") as opened:
        code = enroll(opened.store, "novice", study=opened.study.name).code
        logs: list[str] = []
        # a person of the protocol's shipped population (as `simulate` and `run --rehearse --virtual` draw them)
        from studyctl.populations import SHIPPED, population_for  # noqa: PLC0415

        population = population_for(study_protocol(opened.study), SHIPPED)
        result = run_session(opened.store, code, virtual=True, rehearse=True, log=logs.append, population=population)
        assert result.status == "completed" and result.trials_completed == 4 and result.trials_aborted == 0
        assert any("virtual participant virtual_palpator acts on it" in m for m in logs), logs
        sid = result.session_id
        assert session_is_rehearsal(opened.store, sid)
        events = _events(opened.store, sid)
        kinds = [k for k, _ in events]
        assert [p["name"] for k, p in events if k == "population"] == ["bio_inspired_palpation"]
        assert kinds.count("servo_timing") == 4  # every trial ran on the emulated hardware, in the servo process
        assert [p.get("world") for k, p in events if k == "device_identity"] == ["palpation_board"] * 4
        faults = [p for k, p in events if k == "device_fault" and p.get("rule") not in TIMING_FAULTS]
        assert faults == []
        # the same person throughout: what it learnt in each child process came back (trials_done 1, 2, 3, 4); a
        # person who practises (population v5) also stores its memory after each condition's practice, which is
        # not a trial (trials_done unchanged), and practised on the emulated board before each trial
        done = [p["memory"]["trials_done"] for k, p in events if k == "participant_memory"]
        practised = bool(population.params({t.name: t.value(0.0) for t in population.traits}).get("familiarise"))
        assert done == ([0, 1, 1, 2, 2, 3, 3, 4] if practised else [1, 2, 3, 4]), done
        assert kinds.count("practice_trial_loop_end") == (4 if practised else 0)
        assert kinds.count("report") >= 4  # it acted: grid-cell reports from what it felt and saw
        for tid in range(1, 5):
            s = read_samples(opened.store.db, tid)
            # the sensor force came from the hand's press in the world, through the emulated 10-bit ADC
            assert s["force_n"].max() > 0.3 and s["force_n"].corr(s["depth_mm"]) > 0.7, tid
        balloon = {}
        with opened.store.reading() as q:
            from studyctl.store.models import Trial  # noqa: PLC0415

            for tid, cond in q.execute(Trial.__table__.select().with_only_columns(Trial.id, Trial.condition)
                                       .where(Trial.session_id == sid)):
                balloon[cond] = float(read_samples(opened.store.db, tid)["balloon_pct"].max())
        assert balloon["no_feedback"] == 0.0 and min(v for c, v in balloon.items() if c != "no_feedback") > 10, balloon
        # a rehearsal: never analysed, not progress, the participant has not taken part
        reader = StudyReader(opened.store, opened.study)
        assert reader.trials == () and reader.sessions == ()
        assert all(r.session_id is None for r in study_progress(opened.store, opened.study.name).rows)
        assert opened.store.get_participant(opened.study.id, code).status == "enrolled"


def test_the_cli_rehearses_virtually_with_the_shipped_population(study):
    """`run --rehearse --virtual` draws its person from the protocol's shipped population and says which (the
    engine itself takes whatever population its caller gives: it does not reach up to the populations layer)."""
    from studyctl.cli.session import _shipped_population  # noqa: PLC0415

    opened, _code = study("bio_inspired_palpation")
    logs: list[str] = []
    population = _shipped_population(opened, logs.append)
    assert population.name == "bio_inspired_palpation" and population.participant == "virtual_palpator"
    assert len(logs) == 1 and logs[0].startswith("population: bio_inspired_palpation"), logs


def test_a_virtual_rehearsal_needs_an_emulator_with_a_world(study):
    """The serial board's emulator has no world for a hand: one clear error before anything is written."""
    from studyctl.devices.emulation import emulated  # noqa: PLC0415
    from studyctl.errors import SessionError  # noqa: PLC0415

    with pytest.raises(SessionError, match="no world for a virtual participant"), \
            emulated({"plugin": "serial_driver_board", "params": {}}, world=True):
        pass


REPORT = {"bio_inspired_palpation": "3 4", "needle_insertion": None, "data_driven_palpation": "10 20",
          "pseudo_haptic_palpation": "10 20"}


@pytest.mark.parametrize("protocol", sorted(REPORT))
def test_each_reference_protocol_rehearses_with_a_script(study, protocol):
    """The issue's goal: a scripted rehearsal of each of the four reference protocols completes (4 of 4). Hardware
    devices (the driver board, the omega.6) run on their emulators in the servo process."""
    opened, code = study(protocol)
    answer = REPORT[protocol]
    actions = ([{"t": 0.2, "request": "report", "answer": answer}] if answer else []) + [
        {"t": 0.5, "request": "finish"}]
    script = Script.from_mapping({"default_likert": 1, "trials": {i: actions for i in range(1, 16)},
                                  "outcomes": [{"duration_s": 30, "reports": [answer or "1 1"]}] * 4})
    logs: list[str] = []
    result = run_session(opened.store, code, virtual=False, script=script, rehearse=True, log=logs.append)
    assert result.status == "completed" and result.trials_aborted == 0 and result.trials_completed > 0, logs
    events = _events(opened.store, result.session_id)
    kinds = [k for k, _ in events]
    # a loaded machine may make the 1 kHz loop miss a deadline (the safety layer then holds the device safe for a
    # tick: a timing fault, not a device one); no other device fault may happen
    faults = [p for k, p in events if k == "device_fault" and p.get("rule") not in ("missed_deadline", "loop_stalled")]
    assert faults == []
    hardware = protocol in ("bio_inspired_palpation", "needle_insertion")
    assert ("servo_timing" in kinds) == hardware  # only hardware runs in the servo process
    assert any(m.startswith("rehearsal:") and ("emulated" in m) == hardware for m in logs), logs


def test_a_stored_calibration_is_used_and_linked_by_later_sessions(study):
    from studyctl.engine.device_check import calibrate_device, latest_calibration  # noqa: PLC0415

    opened, code = study("bio_inspired_palpation", "novice")
    cal = calibrate_device(opened.store, opened.study, "udp_driver_board", emulate=True, seconds=0.3)
    assert cal.emulated and set(cal.params) == {"zero_n"} and cal.detail["samples"] > 5 and cal.created_at
    assert latest_calibration(opened.store, opened.study.id, "udp_driver_board", emulated=False) is None
    assert latest_calibration(opened.store, opened.study.id, "udp_driver_board", emulated=True).id == cal.id
    result = run_session(opened.store, code, virtual=False, script=_script(4, 0.3), rehearse=True)
    linked = [p for k, p in _events(opened.store, result.session_id) if k == "device_calibration"]
    assert linked == [{"calibration_id": cal.id, "device": "udp_driver_board", "created_at": cal.created_at,
                       "params": cal.params}]


def test_a_missing_sdk_stops_a_real_session_before_anything_is_written(study, monkeypatch):
    import sys  # noqa: PLC0415

    from studyctl.errors import DeviceError  # noqa: PLC0415

    # as if not installed, whatever an earlier test put on sys.path (the SDK stand-in of an emulated omega6)
    monkeypatch.setitem(sys.modules, "forcedimension_core", None)
    monkeypatch.setitem(sys.modules, "forcedimension_core.dhd", None)  # a stand-in submodule loaded earlier, too
    opened, code = study("needle_insertion")
    with pytest.raises(DeviceError, match=r"pip install 'studyctl\[omega\]'"):
        run_session(opened.store, code, virtual=False, script=_script(1))
    assert opened.store.list_sessions(opened.store.get_participant(opened.study.id, code).id) == []
