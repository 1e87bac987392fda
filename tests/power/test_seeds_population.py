"""Seeds derived from (master seed, sample size, replicate); the population knobs and the participant wrapper."""

from __future__ import annotations

import numpy as np
import pytest
from power_testdata import PROTOCOL

from studyctl.errors import ModelParameterError, UsageError
from studyctl.plugins.interfaces import Action, Participant
from studyctl.power.population import Population, PopulationParticipant, load_population, param_space
from studyctl.power.seeds import replicate_seeds


def test_replicate_seeds_depend_only_on_master_size_and_index():
    a = replicate_seeds(7, 12, 3)
    b = replicate_seeds(7, 12, 3)
    assert a.study_seed == b.study_seed and a.session_seeds == b.session_seeds
    assert a.population_rng().normal() == b.population_rng().normal()
    assert len(a.session_seeds) == 12 and len(set(a.session_seeds)) == 12
    others = [replicate_seeds(7, 12, 4), replicate_seeds(7, 16, 3), replicate_seeds(8, 12, 3)]
    assert len({a.study_seed, *(o.study_seed for o in others)}) == 4
    assert 0 <= a.study_seed < 2**63
    # documented derivation: SeedSequence(master, spawn_key=(n, r)), first child = study seed
    child = np.random.SeedSequence(7, spawn_key=(12, 3)).spawn(3)[0]
    assert a.study_seed == int(child.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def _protocol():
    from studyctl.protocol import load_protocol

    return load_protocol(PROTOCOL)


def test_population_values_are_additive_and_clipped():
    from studyctl.power import population_model

    pop = Population(baseline={"balloon_weber": 0.2}, condition_effects={"linear": {"balloon_weber": 0.1}},
                     group_effects={"expert": {"aim_sd_mm": -1.5, "balloon_weber": -0.05}},
                     between_sd={"aim_sd_mm": 0.3})
    model = population_model(pop, _protocol())
    vals, clipped = model.values("expert", "linear", {"aim_sd_mm": 0.25})
    assert vals == pytest.approx({"balloon_weber": 0.2 + 0.1 - 0.05, "aim_sd_mm": 2.0 - 1.5 + 0.25})
    assert clipped == 0
    vals, clipped = model.values("expert", "no_feedback", {"aim_sd_mm": -3.0})
    assert vals["aim_sd_mm"] == 0.0 and clipped == 1  # aim_sd_mm is declared in [0, 10]
    frame = model.to_frame()
    assert list(frame["parameter"]) == ["aim_sd_mm", "balloon_weber"]
    row = frame.set_index("parameter").loc["balloon_weber"]
    assert row["base"] == 0.2 and row["condition:linear"] == 0.1 and row["group:expert"] == -0.05
    # offsets are drawn in a fixed order from the given Generator
    a = model.draw_offsets(np.random.default_rng(1))
    assert a == model.draw_offsets(np.random.default_rng(1)) and set(a) == {"aim_sd_mm"}


@pytest.mark.parametrize(
    ("pop", "message"),
    [
        (Population(condition_effects={"linearr": {"balloon_weber": 0.1}}), "no condition 'linearr'"),
        (Population(group_effects={"surgeon": {"aim_sd_mm": 0.1}}), "no group (stratum) 'surgeon'"),
        (Population(between_sd={"ballon_weber": 0.1}), "did you mean 'balloon_weber'"),
        (Population(between_sd={"confirm_presses": 1.0}), "not a real number"),
        (Population(condition_effects={"linear": {"balloon_weber": 5.0}}), "outside virtual_palpator's range"),
    ],
)
def test_population_mistakes_are_named(pop, message):
    from studyctl.power import population_model

    with pytest.raises(UsageError, match=message.replace("(", r"\(").replace(")", r"\)")):
        population_model(pop, _protocol())


def test_population_yaml_and_bad_values(tmp_path):
    f = tmp_path / "pop.yaml"
    f.write_text("population:\n  condition_effects:\n    linear: {balloon_weber: -0.02}\n"
                 "  between_sd: {aim_sd_mm: 0.5}\n", encoding="utf-8")
    pop = load_population(f)
    assert pop.condition_effects["linear"]["balloon_weber"] == -0.02 and pop.between_sd == {"aim_sd_mm": 0.5}
    f.write_text("population:\n  betwen_sd: {aim_sd_mm: 0.5}\n", encoding="utf-8")
    with pytest.raises(Exception, match="unknown key"):
        load_population(f)
    with pytest.raises(UsageError, match="must be ≥ 0"):
        Population(between_sd={"aim_sd_mm": -1})
    with pytest.raises(UsageError, match="finite number"):
        Population(baseline={"aim_sd_mm": "wide"})


def test_needle_operator_parameters_come_from_its_defaults():
    from studyctl.participants.needle_operator import DEFAULTS, VirtualNeedleOperator

    space = param_space(VirtualNeedleOperator)
    assert set(space) == set(DEFAULTS)
    assert space["force_weber"].low == 0.0 and space["force_weber"].default == DEFAULTS["force_weber"]


class _Toy(Participant):
    """Remembers things across trials (like the needle operator's traits)."""

    name = "toy"

    def __init__(self, params=None):
        super().__init__(params)
        if self.params.get("gain", 1.0) <= 0:
            raise ModelParameterError("gain must be > 0")
        self.traits = None
        self.history = []

    def begin_trial(self, info, rng):
        if self.traits is None:
            self.traits = {"drawn_in": info.condition}
        self.history.append(info.condition)
        self.current = info.condition

    def act(self, t, percept):
        return Action(inputs={"gain": self.params["gain"]})

    def answer(self, item, rng):
        return int(self.params["gain"] * 10)


def test_population_participant_uses_the_condition_parameters_and_keeps_its_memory():
    from studyctl.plugins.interfaces import TrialInfo

    actor = PopulationParticipant(_Toy, {"a": {"gain": 1.0}, "b": {"gain": 2.0}})
    rng = np.random.default_rng(0)
    for cond, gain in (("a", 1.0), ("b", 2.0), ("a", 1.0)):
        actor.begin_trial(TrialInfo(condition=cond, time_limit_s=10, rate_hz=50), rng)
        assert actor.act(0.0, {}).inputs["gain"] == gain
    inst_b = actor.instance_for("b")
    assert inst_b.traits == {"drawn_in": "a"}  # drawn once, in the first trial, and kept
    assert inst_b.history == ["a", "b", "a"]
    assert actor.answer({"condition": "b"}, rng) == 20
    same = PopulationParticipant(_Toy, {"a": {"gain": 1.0}, "b": {"gain": 1.0}})
    assert same.instance_for("a") is same.instance_for("b")
    with pytest.raises(ModelParameterError):
        PopulationParticipant(_Toy, {}).act(0.0, {})
