"""Sponge phantom scene, simulated palpation device, and building only what a trial needs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.controllers import bio_inspired
from studyctl.controllers.bio_inspired import BioInspiredController
from studyctl.controllers.palpation import LinearController, NoFeedback, PiecewiseController
from studyctl.devices.palpation import SimulatedPalpationDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.errors import DeviceError, ModelParameterError
from studyctl.models import capr
from studyctl.plugins.interfaces import Action, Observation, Participant, TrialInfo
from studyctl.scenes.sponge import SpongePhantomScene, hexagon_holes, tumour_under_probe

RNG = np.random.default_rng(0)
PLACEMENT = {"sites": {"soft": 1, "medium": 3, "hard": 7}, "orientation_deg": None}


def scene(placement=PLACEMENT, needs=frozenset(), spec=None):
    return SpongePhantomScene.build(spec or {}, placement, needs, RNG)


# -- scene -------------------------------------------------------------------------------------------


def test_sponge_force_is_a_flat_punch_and_tumours_stiffen_it_in_order():
    s = scene()
    k = 2 * 4.75e-3 * 50e3 / (1 - 0.09) * 1e-3  # N per mm: Sneddon 2aE*
    assert s.force_n(10.0, 130.0, 2.0) == pytest.approx(2 * k, rel=1e-3)  # far from every hole
    holes = hexagon_holes()
    f = {c: s.force_n(*holes[h - 1], 2.0) for c, h in PLACEMENT["sites"].items() if c != "orientation_deg"}
    sponge = s.force_n(10.0, 130.0, 2.0)
    assert sponge < f["soft"] < f["medium"] < f["hard"]
    assert f["soft"] / sponge == pytest.approx(48 / (18 + 30 * 50 / 58), rel=1e-3)  # column model ratio
    assert f["hard"] / sponge == pytest.approx(48 / (18 + 30 * 50 / 120), rel=1e-3)
    assert s.force_n(*holes[0], 0.0) == 0.0 and s.force_n(*holes[0], -3.0) == 0.0
    assert s.force_n(-1.0, 50.0, 2.0) == 0.0 and s.force_n(50.0, 141.0, 2.0) == 0.0
    # a neighbouring cell (20 mm away) barely feels it
    x, y = holes[6]
    assert s.force_n(x + 20, y, 2.0) / sponge < 1.03
    sensed = s.sense({"x_mm": x, "y_mm": y, "depth_mm": 2.0})
    assert sensed["force_n"] == f["hard"]
    assert sensed["pressure_kpa"] == pytest.approx(f["hard"] / (math.pi * (9.53e-3 / 2) ** 2) / 1e3)
    assert s.sense({}) == {"force_n": 0.0, "pressure_kpa": 0.0}


def test_truth_public_and_contact_helper():
    s = scene()
    truth = s.truth()
    assert {t["class"]: (t["hole"], t["col"], t["row"]) for t in truth["tumours"]} == {
        "soft": (1, 6, 4), "medium": (3, 3, 6), "hard": (7, 4, 4)}
    assert s.public() == {"grid": {"columns": 7, "rows": 7, "cell_mm": 20.0, "origin_mm": [0.0, 0.0]},
                          "size_mm": [140.0, 140.0, 48.0], "holes": 7}
    assert "tumours" not in s.public()
    assert tumour_under_probe(truth, 70.0, 70.0) == "hard"
    assert tumour_under_probe(truth, 70.0 + 9.7, 70.0) == "hard"  # footprints overlap: 5 + 4.75 mm
    assert tumour_under_probe(truth, 70.0 + 10.0, 70.0) is None


def test_scene_builds_only_what_the_trial_needs():
    assert scene().parts == {"sponge", "tumour:soft", "tumour:medium", "tumour:hard"}
    one = scene({"sites": {"hard": 2}})
    assert one.parts == {"sponge", "tumour:hard"} and len(one.tumours) == 1
    assert scene({}).parts == {"sponge"}
    assert scene().view({"x_mm": 1, "y_mm": 2}) is None
    viewed = scene(needs=frozenset({"view", "capr"}))
    assert "view" in viewed.parts and viewed.view({"x_mm": 1, "y_mm": 2})["probe_mm"] == (1.0, 2.0)
    assert scene({"soft": 4}).tumours[0].hole == 4  # a plain {class: hole} mapping works too


@pytest.mark.parametrize(
    ("placement", "spec", "message"),
    [
        ({"sites": {"squishy": 1}}, None, "placement names tumour 'squishy'; known classes: soft, medium, hard"),
        ({"sites": {"soft": 8}}, None, "tumour 'soft' is in hole 8; holes are 1..7"),
        ({"sites": {"soft": 2, "hard": 2}}, None, "are both placed in hole 2"),
        ({}, {"params": {"tumour_height_mm": 50}}, "parameter 'tumour_height_mm' = 50 is out of range"),
        ({}, {"params": {"size_mm": [140, 140, 20]}}, "tumour_height_mm 30.0 must be below the sponge thickness"),
        ({}, {"params": {"grid": {"columns": 0, "rows": 7, "cell_mm": 20}}}, "grid {'columns': 0"),
        ({}, {"params": {"holes_mm": [[500, 10]]}}, "hole 1 at [500, 10] lies outside the sponge"),
        ({}, {"params": {"tumour_kpa": {"soft": -1}}}, "tumour_kpa['soft'] = -1 must be in (0, 1e5]"),
        ({}, {"params": {"sponge": 50}}, "unknown parameter 'sponge'; did you mean 'sponge_kpa'?"),
    ],
)
def test_bad_scene_input(placement, spec, message):
    with pytest.raises(ModelParameterError) as err:
        scene(placement, spec=spec)
    assert message in str(err.value)


# -- only the models a condition uses ----------------------------------------------------------------


def test_baseline_controllers_build_no_afferent_model(monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("a CAPR population was built for a condition that does not use it")

    monkeypatch.setattr(capr.CaprModel, "__init__", forbidden)
    monkeypatch.setattr(capr, "build_population", forbidden)
    monkeypatch.setattr(bio_inspired, "_MODELS", {})  # none built yet in this process: the bio-inspired one must build
    for cls in (NoFeedback, LinearController, PiecewiseController):
        ctrl = cls({})
        assert cls.needs({}) == frozenset()
        ctrl.step(Observation(0.0, {"force_n": 0.5}))
        assert not any(isinstance(v, capr.CaprModel) for v in vars(ctrl).values())
    with pytest.raises(AssertionError, match="was built"):
        BioInspiredController({})


def test_bio_inspired_builds_only_the_afferent_types_its_actuators_read():
    assert BioInspiredController({}).model.types == ("SA1", "RA1", "PC")
    assert BioInspiredController({"drive": ["balloon"]}).model.types == ("SA1",)
    assert BioInspiredController({"weights": [0.29, 0.36, 0.0]}).model.types == ("SA1", "RA1")
    assert BioInspiredController({"drive": ["vibration"], "weights": [0, 0.36, 0.46]}).model.types == ("RA1", "PC")
    assert BioInspiredController.needs({}) == frozenset({"capr"})


def test_contact_population_simulates_only_the_afferents_under_the_contact():
    full = BioInspiredController({}).model
    contact = BioInspiredController({"population": "contact"}).model
    for pop in contact.populations:
        assert pop.in_contact.all()
    assert contact.n_units < full.n_units / 3
    bigger = BioInspiredController({"population": "contact", "contact_radius_mm": 5.5}).model
    assert bigger.n_units > contact.n_units


# -- simulated device --------------------------------------------------------------------------------


def test_device_reads_the_scene_through_the_adc():
    s = scene()
    dev = SimulatedPalpationDevice({"sensor_noise_lsb": 0.0}, s, np.random.default_rng(1))
    with pytest.raises(DeviceError, match="read before open"):
        dev.read(0.0)
    dev.open()
    dev.apply_input({"x_mm": 70.0, "y_mm": 70.0, "depth_mm": 2.0})
    obs = dev.read(0.0)
    # the compliant forceps yields: the tip reaches d = 2 / (1 + c·K) mm, K the sponge's stiffness here
    k = s.force_n(70.0, 70.0, 1.0)
    tip = 2.0 / (1 + dev.params["instrument_compliance_mm_per_n"] * k)
    assert obs.values["depth_mm"] == pytest.approx(tip) and tip < 2.0
    f = s.force_n(70.0, 70.0, tip)
    assert obs.values["adc"] == dev.sensor.counts(f)
    assert abs(obs.values["force_n"] - f) < 0.01  # one ADC step
    assert obs.values["probe_x_mm"] == 70.0 and obs.sample_t == 0.0 and obs.faults == ()
    noisy = SimulatedPalpationDevice({"sensor_noise_lsb": 3.0}, s, np.random.default_rng(1))
    noisy.open()
    noisy.apply_input({"x_mm": 70.0, "y_mm": 70.0, "depth_mm": 2.0})
    counts = [noisy.read(k / 50).values["adc"] for k in range(200)]
    assert 1.5 < np.std(counts) < 4.5 and abs(np.mean(counts) - obs.values["adc"]) < 1.0


def test_actuators_follow_commands_with_their_dynamics():
    dev = SimulatedPalpationDevice({}, None, np.random.default_rng(1))
    dev.open()
    dev.read(0.0)
    dev.write({"balloon_pct": 96.0, "vibration_pct": 100.0})
    dev.read(0.05)
    fb = dev.feedback()
    assert 0 < fb["balloon_psi"] < 15.0 and 0 < fb["vibration_ms2"] < 12.0
    dev.read(2.0)
    fb = dev.feedback()
    assert fb["balloon_psi"] == pytest.approx(15.0) and fb["vibration_hz"] == pytest.approx(250.0)
    dev.close()
    dev.close()  # twice is fine


class Presser(Participant):
    name = "presser"

    def begin_trial(self, info, rng):
        pass

    def act(self, t, percept):
        return Action(inputs={"x_mm": 70.0, "y_mm": 70.0, "depth_mm": 2.0})


@pytest.mark.parametrize("kind", ["stale", "adc_out_of_range", "nan"])
def test_device_faults_hold_the_actuators_off(kind):
    s = scene()
    dev = SimulatedPalpationDevice({"faults": [{"kind": kind, "start_s": 1.0, "end_s": 1.5}]}, s,
                                   np.random.default_rng(2))
    dev.open()
    samples, events = [], []
    out = run_trial(
        info=TrialInfo("bio", 3.0, 50.0), controller=BioInspiredController({}, s), device=dev, participant=Presser(),
        clock=SimulatedClock(), rng=np.random.default_rng(3), on_sample=lambda t, v: samples.append((t, dict(v))),
        on_event=lambda t, k, p: events.append((t, k, dict(p))),
    )
    assert out.ended_by == "time_limit"
    faults = [(t, p["rule"]) for t, k, p in events if k == "device_fault"]
    recovered = [t for t, k, p in events if k == "device_recovered"]
    assert faults and len({t for t, _ in faults}) == 1  # one episode (an ADC glitch is also a NaN force)
    assert recovered and recovered[0] == pytest.approx(1.5, abs=0.03)
    fault_t = faults[0][0]
    assert 1.0 <= fault_t <= 1.13  # stale: once the sample is older than 0.1 s
    during = [v for t, v in samples if fault_t <= t < 1.5]
    assert during and all(v["balloon_pct"] == 0.0 and v["vibration_pct"] == 0.0 for v in during)
    before = [v for t, v in samples if 0.5 <= t < 1.0]
    assert all(v["balloon_pct"] > 36.0 for v in before)
    if kind == "adc_out_of_range":
        assert {r for _, r in faults} == {"sensor_fault", "sensor_non_finite"}
        assert any(math.isnan(v["force_n"]) for _, v in samples)


def test_bad_fault_spec():
    with pytest.raises(ModelParameterError, match="fault .* must be a mapping with kind in stale"):
        SimulatedPalpationDevice({"faults": [{"kind": "fire"}]})
    with pytest.raises(ModelParameterError, match="needs 0 ≤ start_s < end_s"):
        SimulatedPalpationDevice({"faults": [{"kind": "nan", "start_s": 2, "end_s": 1}]})


def test_effect_of_the_chosen_lateral_spread():
    """σ (chosen, 8 mm) sets how far from a tumour its stiffness is felt: wider σ, more at the next cell."""
    x, y = hexagon_holes()[6]
    ratio = {}
    for sigma in (4.0, 8.0, 16.0):
        s = scene({"sites": {"hard": 7}}, spec={"params": {"lateral_sigma_mm": sigma}})
        ratio[sigma] = s.force_n(x + 20, y, 2.0) / s.force_n(10.0, 130.0, 2.0)
        assert s.force_n(x, y, 2.0) == pytest.approx(scene({"sites": {"hard": 7}}).force_n(x, y, 2.0))  # on top
    assert 1.0 <= ratio[4.0] < ratio[8.0] < ratio[16.0]
    assert ratio[16.0] > 1.2


# -- per-tick fast paths: the same numbers as the model methods --------------------------------------------


def test_view_parts_draws_the_view_of_the_merged_channels():
    s = scene(needs=frozenset({"view"}))
    rng = np.random.default_rng(3)
    keys = ("x_mm", "y_mm", "depth_mm", "force_n")
    for _ in range(200):
        parts = [{k: float(rng.uniform(-5, 150)) for k in keys if rng.random() < 0.5} for _ in range(3)]
        assert s.view_parts(*parts) == s.view({**parts[0], **parts[1], **parts[2]})
    assert scene().view_parts({}, {}, {}) is None  # no view built


def test_device_read_equals_the_model_methods_tick_by_tick():
    """read() keeps the sensor table, the scene's force function and the lags' decay between ticks; each
    tick must equal what the model methods compute from scratch (with the same noise draws)."""
    from studyctl.devices.palpation import forceps_contact
    from studyctl.models.palpation_hw import A201, BalloonModel, VibrationMotorModel

    s = scene()
    dev = SimulatedPalpationDevice({}, scene=s, rng=np.random.default_rng(11))
    noise = np.random.default_rng(11)
    balloon, motor = BalloonModel(), VibrationMotorModel()
    dev.open()
    rng = np.random.default_rng(5)
    psi = speed = 0.0
    command = {"balloon_pct": 0.0, "vibration_pct": 0.0}
    t, last = 0.0, None
    for k in range(3000):
        t += 0.02 if k % 7 else 0.02 * (1 + rng.random())  # mostly equal ticks, some not
        inputs = {"x_mm": float(rng.uniform(0, 140)), "y_mm": float(rng.uniform(0, 140)),
                  "depth_mm": float(rng.uniform(-2, 12))}
        dev.apply_input(inputs)
        got = dev.read(t).values
        if last is not None:
            psi = balloon.step(psi, command["balloon_pct"], t - last)
            speed = motor.step(speed, command["vibration_pct"], t - last)
        last = t
        depth, force = forceps_contact(s, inputs["x_mm"], inputs["y_mm"], inputs["depth_mm"], 0.5)
        counts = int(min(max(round(A201.count_of_force(force) + 0.5 * noise.standard_normal()), 0), A201.adc_max))
        force_n = A201.force_of_count(counts)
        assert got == {"adc": float(counts), "force_n": force_n, "pressure_kpa": A201.pressure_kpa(force_n),
                       "probe_x_mm": inputs["x_mm"], "probe_y_mm": inputs["y_mm"], "depth_mm": depth}
        assert dev.feedback() == {"balloon_psi": psi, "vibration_hz": motor.output(speed)[0],
                                  "vibration_ms2": motor.output(speed)[1]}
        command = {"balloon_pct": float(rng.uniform(0, 110)), "vibration_pct": float(rng.uniform(0, 100))}
        dev.write(command)


def test_held_and_partial_commands_give_the_model_lags_tick_by_tick():
    """The device holds each command's actuator targets and the motor's output between ticks (a loop writes the
    same command for many ticks): held, repeated, one-channel and off commands must still give, every tick, what
    the models compute from scratch, bit for bit, and a new command must move the lag at once."""
    from studyctl.models.palpation_hw import BalloonModel, VibrationMotorModel

    dev = SimulatedPalpationDevice({}, scene=scene(), rng=np.random.default_rng(2))
    balloon, motor = BalloonModel(), VibrationMotorModel()
    dev.open()
    rng = np.random.default_rng(9)
    command = {"balloon_pct": 0.0, "vibration_pct": 0.0}
    psi = speed = 0.0
    t, last = 0.0, None
    for k in range(2000):
        t += 0.02
        dev.apply_input({"x_mm": 70.0, "y_mm": 70.0, "depth_mm": 3.0})
        dev.read(t)
        if last is not None:
            psi = balloon.step(psi, command["balloon_pct"], t - last)
            speed = motor.step(speed, command["vibration_pct"], t - last)
        last = t
        hz, ms2 = motor.output(speed)
        assert dev.feedback() == {"balloon_psi": psi, "vibration_hz": hz, "vibration_ms2": ms2}, k
        phase = (k // 50) % 4
        if phase == 0:  # off: the lags settle to exactly zero and stay there
            new = {"balloon_pct": 0.0, "vibration_pct": 0.0}
        elif phase == 1:  # the same command written again every tick
            new = {"balloon_pct": 80.0, "vibration_pct": 60.0}
        elif phase == 2:  # one channel at a time, the other held
            name, top = ("balloon_pct", 110) if k % 2 else ("vibration_pct", 100)
            new = {name: float(rng.uniform(0, top))}
        else:  # a command held for runs of ticks
            new = {"balloon_pct": 40.0 + (k // 10) % 5, "vibration_pct": 30.0 + (k // 10) % 7}
        command = {**command, **new}
        dev.write(new)


def test_sensor_noise_is_the_device_streams_draws_in_order_drawn_in_blocks():
    """read() draws its sensor noise from the device's own Generator a block at a time (a scalar draw a tick cost
    a tenth of the tick): the counts must be those of one draw a tick, in order, across block boundaries and a
    close/open (the stream goes on), and the Generator must be drawn only a whole block at a time."""
    from studyctl.devices.palpation import NOISE_BLOCK, forceps_contact
    from studyctl.models.palpation_hw import A201

    s = scene()
    dev = SimulatedPalpationDevice({"sensor_noise_lsb": 3.0}, scene=s, rng=np.random.default_rng(4))
    scalar = np.random.default_rng(4)
    dev.open()
    for k in range(2 * NOISE_BLOCK + 17):
        if k == NOISE_BLOCK // 2:
            dev.close()
            dev.open()
        x, y, depth = 70.0 + k % 13, 60.0 + k % 7, 1.0 + k % 5
        dev.apply_input({"x_mm": x, "y_mm": y, "depth_mm": depth})
        got = dev.read(0.02 * k).values["adc"]
        if k == 0:  # one block drawn, not one number
            assert dev.rng.bit_generator.state == _drawn(4, NOISE_BLOCK)
        force = forceps_contact(s, x, y, depth, 0.5)[1]
        z = scalar.standard_normal()
        assert got == float(int(min(max(round(A201.count_of_force(force) + 3.0 * z), 0), A201.adc_max))), k


def _drawn(seed: int, draws: int) -> dict:
    """The state of a Generator seeded ``seed`` after ``draws`` standard normals."""
    g = np.random.default_rng(seed)
    g.standard_normal(draws)
    return g.bit_generator.state
