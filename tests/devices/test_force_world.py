"""A virtual participant on the emulated omega.6 (``run --rehearse --virtual`` for the needle study): its hand is in
the emulator's world, the handle moves only by the emulator's physics, and the force reaches the controller only
through the SDK's own API (the adapter reads the encoders; the hand feels what the device applied)."""

from __future__ import annotations

import math

import pytest
from polling import wait_for

pytestmark = pytest.mark.slow


def test_the_hand_moves_the_handle_and_feels_the_applied_force_through_the_emulator():
    from studyctl.devices.emulation import emulated, has_world
    from studyctl.devices.omega import Omega6Device
    from studyctl.devices.touch import TouchDevice
    from studyctl.devices.world import embody

    assert has_world(Omega6Device) and not has_world(TouchDevice)  # Touch's gimbal frame is not mapped yet
    with emulated({"plugin": "omega6", "params": {"offset_mm": [0.0, 0.0, 10.0]}}, world=True) as ref:
        assert ref["world"]["kind"] == "force3d"
        device = embody(Omega6Device(ref["params"]), ref["world"], None)
        device.open()
        try:
            # the hand wants the handle 20 mm along x (scene frame; the device frame is 10 mm lower): the emulator's
            # modelled hand pulls it there, and the adapter reads it from the encoders through the SDK
            device.apply_input({"x_mm": 20.0, "y_mm": 0.0, "z_mm": 10.0, "dir_x": 0.0, "dir_y": 0.0, "dir_z": -1.0,
                                "button": 1.0})
            wait_for(lambda: abs(device.read(0.0).values["x_mm"] - 20.0) < 1.0, timeout=5.0, what="the handle at x 20")
            obs = device.read(0.0).values
            assert abs(obs["z_mm"] - 10.0) < 1.0 and obs["button"] == 1.0
            assert math.isclose(obs["dir_z"], -1.0, abs_tol=1e-9)  # the wrist's pen axis as the adapter reads it
            # a force beyond the device's 12 N is clamped by the device; the hand feels what was applied, and it
            # pushes the handle off the hand's target (the modelled hand is a 300 N/m spring)
            # pushed until the handle is off (commanding all along, as the device's watchdog wants): a fixed 100 x
            # 2 ms of pushing raced the emulator's physics process on a loaded machine
            def pushed_off():
                device.write({"fx_n": 30.0, "fy_n": 0.0, "fz_n": 0.0})
                return device.read(0.0).values["x_mm"] > 40.0

            wait_for(pushed_off, timeout=10.0, what="the 12 N push to move the handle past x 40", interval=0.002)
            felt = device.feedback()
            assert math.isclose(felt["fx_n"], 12.0, rel_tol=1e-6)
            # no more commands: the device's own watchdog turns the force off, and the hand feels nothing
            wait_for(lambda: device.feedback()["fx_n"] == 0.0, timeout=2.0, what="no force once released")
        finally:
            device.close()


def test_a_virtual_participant_rehearses_the_needle_study_on_the_emulated_omega6(tmp_path):
    from sqlalchemy import select

    from studyctl.engine.api import run_session, session_is_rehearsal
    from studyctl.engine.trial_loop import TIMING_FAULTS
    from studyctl.populations import SHIPPED, population_for
    from studyctl.protocol.loader import resolve_protocol
    from studyctl.store.enrollment import enroll, study_protocol
    from studyctl.store.models import Event, Trial
    from studyctl.store.samples import read_samples
    from studyctl.store.workspace import init_workspace, open_study

    # the shipped protocol, one repetition of each scenario with a 6 s limit (hardware runs in real time)
    text = resolve_protocol("needle_insertion").read_text()
    text = text.replace("repetitions: 3 ", "repetitions: 1 ").replace("time_limit_s: 90", "time_limit_s: 6")
    text = text.replace("max_s: 900 ", "max_s: 2 ")
    assert "repetitions: 1 " in text and "time_limit_s: 6" in text
    (tmp_path / "ndl.yaml").write_text(text)
    init_workspace(tmp_path / "ws", protocol=str(tmp_path / "ndl.yaml"))
    with open_study(workspace=tmp_path / "ws") as opened:
        store = opened.store
        code = enroll(store, study=opened.study.name).code
        logs: list[str] = []
        population = population_for(study_protocol(opened.study), SHIPPED)
        result = run_session(store, code, virtual=True, rehearse=True, log=logs.append, population=population)
        assert result.status == "completed" and result.trials_completed == 5 and result.trials_aborted == 0
        assert any("virtual participant virtual_needle_operator acts on it" in m for m in logs), logs
        assert session_is_rehearsal(store, result.session_id)
        with store.reading() as s:
            trials = list(s.scalars(select(Trial).where(Trial.session_id == result.session_id).order_by(Trial.id)))
            pids = set()
            for trial in trials:
                rows = s.execute(select(Event.kind, Event.payload).where(Event.trial_id == trial.id)).all()
                ident = [p for k, p in rows if k == "device_identity"]
                assert [(p["model"], p["world"]) for p in ident] == [("omega.6", "force3d")]
                pids |= {p["rt"]["pid"] for k, p in rows if k == "servo_timing"}
                faults = [p for k, p in rows if k == "device_fault"
                          and p.get("rule") not in TIMING_FAULTS]
                assert faults == []
                frame = read_samples(store.db, trial.id)
                # the hand moved the handle (down towards the liver), read back through the SDK's encoders
                assert frame["z_mm"].max() - frame["z_mm"].min() > 10.0
                assert set(frame["button"].unique()) <= {0.0, 1.0}
        assert len(pids) == 1  # one servo process for the whole session
        # the guided scenarios rendered force on the handle (commanded through the SDK, felt through the world)
        forces = [read_samples(store.db, t.id)[["fx_n", "fy_n", "fz_n"]].abs().to_numpy().max() for t in trials]
        assert max(forces) > 0.5
