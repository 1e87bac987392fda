"""Simulated sessions at a reduced loop rate: which conditions it touches, what the device keeps, what is stored."""

from __future__ import annotations

import pytest

from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.engine.factory import EntryPointFactory
from studyctl.engine.loop_rates import simulation_rates
from studyctl.engine.plan import ConditionSpec, SessionPlan, Step
from studyctl.errors import SessionError, UsageError
from studyctl.workflows.simulate import create_cohort, run_participant


def _plan() -> SessionPlan:
    conditions = {
        "manual": ConditionSpec("manual", manual=True),
        "ff": ConditionSpec("ff", controller="stiffness_map_ff"),
        "needle": ConditionSpec("needle", controller="needle_hybrid"),
        "linear": ConditionSpec("linear", controller="linear"),
    }
    steps = tuple(Step(i, "trial", condition=c) for i, c in enumerate(conditions, start=1))
    return SessionPlan(steps=steps, conditions=conditions)


def test_only_rate_adjustable_controllers_faster_than_the_cap_are_slowed():
    plan = _plan()
    rates = simulation_rates(plan, EntryPointFactory(), 250.0)
    # the tissue controller (1 kHz, integrates with the measured step) and the needle controller (its per-step
    # cross-fade rescaled by set_loop_rate) are capped; the linear controller already runs at 50 Hz, a manual
    # condition runs no controller
    assert rates == {"ff": 250.0, "needle": 250.0}
    capped = plan.with_condition_rates(rates)
    assert capped.conditions["ff"].rate_hz == 250.0
    assert capped.conditions["needle"].rate_hz == 250.0
    assert capped.conditions["linear"].rate_hz is None
    assert SessionPlan.from_json(capped.to_json()).conditions["ff"].rate_hz == 250.0  # stored, so a resume keeps it
    assert simulation_rates(plan, EntryPointFactory(), 5000.0) == {}


@pytest.mark.parametrize("bad", [0.0, -10.0, float("inf"), float("nan")])
def test_a_bad_rate_is_refused(bad):
    with pytest.raises(UsageError, match="simulation loop rate.* must be a positive number of Hz"):
        simulation_rates(_plan(), EntryPointFactory(), bad)


def test_rates_for_unknown_conditions_are_refused():
    with pytest.raises(SessionError, match="unknown conditions: nope"):
        _plan().with_condition_rates({"nope": 100.0})


def _device() -> SimulatedForceDevice:
    dev = SimulatedForceDevice(params={"hand": "none", "resolution_mm": 1e-6})
    dev.open()
    return dev


def test_a_slower_loop_keeps_the_device_velocity_window_in_time():
    """The handle moves at a constant 50 mm/s; read every tick at 1 kHz or every 4th, the device must report
    the same velocity (its encoder and velocity window keep running at the device's own rate)."""
    speeds = {}
    for every in (1, 4):
        dev = _device()
        for k in range(0, 201, every):
            t = k / 1000.0
            dev.apply_input({"x_mm": 50.0 * t, "y_mm": 0.0, "z_mm": 0.0})
            obs = dev.read(t)
        speeds[every] = obs.values["vx_mm_s"]
    assert speeds[1] == pytest.approx(50.0, rel=1e-3)
    assert speeds[4] == pytest.approx(speeds[1], rel=1e-3)


@pytest.mark.slow
def test_a_cohort_at_a_reduced_rate_runs_and_records_it(tmp_path):
    cohort = create_cohort("data_driven_palpation", 1, 3, tmp_path / "ws", sim_rate_hz=250.0)
    assert run_participant(cohort, cohort.codes[0]) == "completed"
    import sqlite3

    con = sqlite3.connect(cohort.database)
    rows = con.execute("select condition, json_extract(outcome, '$.rate_hz') from trial").fetchall()
    con.close()
    rates = dict(rows)
    assert rates["haptic"] == 250.0  # the 1 kHz stiffness-map controller, capped
    assert rates["manual"] == 50.0  # untouched


def test_a_bad_cohort_rate_is_a_usage_error(tmp_path):
    with pytest.raises(UsageError, match="--sim-rate-hz .* must be a positive number of Hz, got 0.0"):
        create_cohort("data_driven_palpation", 1, 3, tmp_path / "ws", sim_rate_hz=0.0)
    assert not (tmp_path / "ws").exists()  # nothing written


def test_the_unrolled_substeps_are_the_device_integration():
    """``_substeps(n)`` must advance the spring-held handle bit for bit as ``n`` calls of ``_integrate``."""
    devices = []
    for _ in range(2):
        dev = SimulatedForceDevice()
        dev.open()
        dev.apply_input({"x_mm": 1.0, "y_mm": 2.0, "z_mm": 3.0})
        dev.read(0.0)
        dev.apply_input({"x_mm": 4.0, "y_mm": -2.0, "z_mm": 0.5})
        dev.write({"fx_n": 0.3, "fy_n": -0.2, "fz_n": 1.1})
        devices.append(dev)
    devices[0]._substeps(7)
    for _ in range(7):
        devices[1]._integrate(devices[1]._dt)
    assert devices[0]._pos == devices[1]._pos and devices[0]._vel == devices[1]._vel


def test_the_simulate_loop_rate_note_builds_the_protocols_loops_once(monkeypatch):
    # building the loops plans a session and loads every controller; the note needs both the capped rates and
    # whether the cap slows anything, which used to build them twice
    from studyctl.engine import loop_rates as module
    from studyctl.protocol import load_protocol, resolve_protocol
    from studyctl.workflows.simulate import loop_rates_note

    protocol = load_protocol(resolve_protocol("needle_insertion"))
    built = []
    real = module.protocol_loops
    monkeypatch.setattr(module, "protocol_loops", lambda p: built.append(p) or real(p))
    note = loop_rates_note(protocol, 250.0)
    assert len(built) == 1
    assert "250 Hz" in note and "leave --sim-rate-hz out" in note
    built.clear()
    assert "(the protocol's rates)" in loop_rates_note(load_protocol(resolve_protocol("bio_inspired_palpation")), 250.0)
    assert len(built) == 1
