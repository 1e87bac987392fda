"""Population files: loading, bad input, per-person draws, and what a simulated session stores."""

from __future__ import annotations

import json
import math
import sqlite3

import numpy as np
import pytest
from population_testdata import MINI_PLAN, MINI_PROTOCOL, POPULATION, write_variant

from studyctl.errors import NotFoundError, PopulationError
from studyctl.populations import free_params, load_population_file


def test_loads_the_contract_fields(population):
    assert population.name == "palpator_small" and population.version == 1
    assert population.participant == "virtual_palpator"
    assert [t.name for t in population.traits] == sorted(t.name for t in population.traits)
    speed = population.trait("press_speed_mm_s")
    assert (speed.dist, speed.mean, speed.sd, speed.low, speed.high) == ("lognormal", 6.0, 0.3, 2.0, 20.0)
    assert speed.groups["expert"]["mean"] == 9.0
    assert population.fixed == {"hold_s": 0.3}
    import hashlib

    assert population.sha256 == hashlib.sha256(POPULATION.read_bytes()).hexdigest()


def test_draws_are_seeded_stratum_aware_and_clipped(population):
    a = population.draw(np.random.default_rng(5), "novice")
    b = population.draw(np.random.default_rng(5), "novice")
    e = population.draw(np.random.default_rng(5), "expert")
    assert a == b
    # same standard normals, the expert location: the lognormal speed scales by 9/6, other traits equal
    assert e["press_speed_mm_s"] == pytest.approx(a["press_speed_mm_s"] * 9.0 / 6.0)
    assert e["balloon_weber"] == a["balloon_weber"] and a["move_s"] == 0.3
    draws = [population.draw(np.random.default_rng(i), "novice") for i in range(400)]
    z = np.array([d["report_z"] for d in draws])
    assert z.min() >= 1.5 and z.max() <= 6.0
    assert np.mean(z) == pytest.approx(3.5, abs=0.1) and np.std(z) == pytest.approx(0.5, abs=0.06)
    speeds = np.log([d["press_speed_mm_s"] for d in draws])
    assert np.exp(np.median(speeds)) == pytest.approx(6.0, rel=0.06)


def test_common_random_numbers_move_people_smoothly(population):
    (f,) = free_params(population, ["balloon_weber"])
    lo = population.with_values({"balloon_weber": 0.10})
    hi = population.with_values({"balloon_weber": 0.14})
    for seed in range(20):
        a = lo.draw(np.random.default_rng(seed))
        b = hi.draw(np.random.default_rng(seed))
        if 0.03 < b["balloon_weber"] < 0.4 and 0.03 < a["balloon_weber"] < 0.4:
            assert b["balloon_weber"] - a["balloon_weber"] == pytest.approx(0.04)
        assert a["report_z"] == b["report_z"]
    assert lo.sha256 != hi.sha256 != population.sha256
    assert f.low == 0.03 and f.high == 0.4


def test_an_appended_trait_keeps_every_person_s_other_traits(tmp_path):
    # A trait added to a shipped population must not swap the people a landing rule pairs by seed: without
    # `appended`, follow_gain_mm_per_ns sorts in third and every later trait (force_threshold_n ...) would take
    # another person's standard normal.
    from studyctl.engine.seeding import person_traits
    from studyctl.populations.loader import shipped_population_path

    shipped = shipped_population_path("needle_insertion")
    trait = ("  follow_gain_mm_per_ns:\n    dist: lognormal\n    mean: 3.0\n    sd: 0.4\n    range: [0.75, 12.0]\n"
             "    appended: true\n    source: \"CHOSEN: test\"\nfixed:\n")
    added = load_population_file(write_variant(tmp_path, "fixed:\n", trait, source=shipped))
    base = load_population_file(shipped)
    assert added.trait("follow_gain_mm_per_ns").appended and not base.trait("finish_mm").appended
    gains = []
    for seed in range(8):
        old, new = person_traits(base, seed, None), person_traits(added, seed, None)
        assert {k: new[k] for k in old} == old
        gains.append(new["follow_gain_mm_per_ns"])
    assert len(set(gains)) == 8 and min(gains) >= 0.75 and max(gains) <= 12.0
    assert "appended: true" in added.to_yaml() and "appended" not in base.to_yaml()
    # sorted in among the others instead, the people change
    mixed = load_population_file(write_variant(tmp_path, "fixed:\n", trait.replace("    appended: true\n", ""),
                                               source=shipped))
    assert person_traits(mixed, 0, None)["force_threshold_n"] != person_traits(base, 0, None)["force_threshold_n"]
    bad = write_variant(tmp_path, "fixed:\n", trait.replace("appended: true", "appended: 1"), source=shipped)
    with pytest.raises(PopulationError, match=r"follow_gain_mm_per_ns\.appended: appended must be true or false"):
        load_population_file(bad)


def test_free_parameter_names(population):
    names = ["press_speed_mm_s", "press_speed_mm_s.sd", "press_speed_mm_s@expert", "hold_s"]
    fs = {f.name: f for f in free_params(population, names)}
    assert fs["press_speed_mm_s"].scale == "log" and fs["press_speed_mm_s@expert"].value == 9.0
    assert fs["press_speed_mm_s.sd"].high == 1.5 and fs["hold_s"].key == "value"
    moved = population.with_values({"press_speed_mm_s@expert": 12.0, "press_speed_mm_s.sd": 0.5})
    assert moved.trait("press_speed_mm_s").groups["expert"]["mean"] == 12.0
    assert moved.trait("press_speed_mm_s").sd == 0.5
    with pytest.raises(PopulationError, match="did you mean 'balloon_weber'"):
        free_params(population, ["balloon_webr"])
    with pytest.raises(PopulationError, match="no free parameters"):
        free_params(population, [])


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("  balloon_weber:\n", "  baloon_weber:\n", r":\d+:\d+: traits\.baloon_weber: .*did you mean 'balloon_weber'"),
        ("dist: lognormal", "dist: lognorml", r":\d+:\d+: traits\.press_speed_mm_s\.dist: .*did you mean 'lognormal'"),
        ("sd: 0.03", "sd: -0.03", r"traits\.balloon_weber\.sd: sd = -0\.03 is negative"),
        ("range: [0.03, 0.4]", "range: [0.0, 2.5]", r"leaves virtual_palpator's allowed range"),
        ("range: [0.03, 0.4]", "range: [0.4, 0.03]", r"must have low < high"),
        ("mean: 0.12", "mean: 0.9", r"location 0\.9 is outside the trait's range"),
        ("participant: virtual_palpator", "participant: virtual_palpatr", r"did you mean 'virtual_palpator'"),
        ("format: studyctl-population/1", "format: studyctl-population/9", r"format .* is not supported"),
        ('source: "CHOSEN: test population, decision criterion"', 'source: "a guess"', r"must start with CITED:"),
        ("fixed: {hold_s: 0.3}", "fixed: {hold_s: 99.0}", r"fixed\.hold_s: .*out of range"),
        ("fixed: {hold_s: 0.3}", "fixed: {hold: 0.3}", r"fixed\.hold: .*did you mean 'hold_s'"),
        ("groups: {expert: {mean: 9.0}}", "groups: {expert: {median: 9.0}}", r"unknown key 'median'"),
    ],
)
def test_bad_population_files_name_file_line_and_fix(tmp_path, old, new, message):
    path = write_variant(tmp_path, old, new)
    with pytest.raises(PopulationError, match=message) as info:
        load_population_file(path)
    assert str(info.value).startswith(str(path) + ":")
    line = int(str(info.value).split(":")[1])
    written = path.read_text().splitlines()
    # the line named is where the bad text (or its trait) is written
    assert any(part in written[line - 1] for part in (new.split(":")[0].strip(), new.strip()[:12], "traits"))


def test_missing_file_is_not_found():
    with pytest.raises(NotFoundError, match="does not exist"):
        load_population_file("no/such/population.yaml")


def test_protocol_of_another_participant_kind_is_refused(population):
    from studyctl.populations import check_population_for
    from studyctl.protocol import load_protocol, resolve_protocol

    proto = load_protocol(resolve_protocol("needle_insertion"))
    with pytest.raises(PopulationError, match="is for participant 'virtual_palpator'.*simulates 'virtual_needle_op"):
        check_population_for(population, proto)


def test_a_population_for_unknown_strata_is_refused(tmp_path):
    from studyctl.populations import check_population_for
    from studyctl.protocol import load_protocol

    pop = load_population_file(write_variant(tmp_path, "{expert: {mean: 9.0}}", "{experts: {mean: 9.0}}"))
    with pytest.raises(PopulationError, match="no stratum 'experts'.*did you mean 'expert'"):
        check_population_for(pop, load_protocol(MINI_PROTOCOL))


def _params_seen(monkeypatch) -> list[dict]:
    """The parameters each VirtualPalpator is built with from now on (the test's own list)."""
    from studyctl.participants.palpator import VirtualPalpator

    seen: list[dict] = []
    real_init = VirtualPalpator.__init__

    def spy(self, params=None):
        seen.append(dict(params or {}))
        real_init(self, params)

    monkeypatch.setattr(VirtualPalpator, "__init__", spy)
    return seen


@pytest.mark.slow
def test_simulated_sessions_store_population_and_traits_and_pass_them_to_the_participant(tmp_path, monkeypatch,
                                                                                       population):
    from studyctl.engine.seeding import person_traits, session_seed
    from studyctl.workflows.simulate import simulate_study

    seen = _params_seen(monkeypatch)
    result = simulate_study(MINI_PROTOCOL, 2, 31, tmp_path / "ws", population=POPULATION)
    assert result.population == "palpator_small v1" and result.population_sha256 == population.sha256
    con = sqlite3.connect(tmp_path / "ws" / "study.db")
    rows = con.execute(
        "select e.session_id, e.kind, e.payload, p.code, p.stratum, s.seed from event e join session s on "
        "s.id = e.session_id join participant p on p.id = s.participant_id where e.kind in "
        "('population', 'session_plan') order by e.seq"
    ).fetchall()
    con.close()
    stored = [r for r in rows if r[1] == "population"]
    assert len(stored) == 2
    for sid, _, payload, code, stratum, seed in stored:
        rec = json.loads(payload)
        assert rec["sha256"] == population.sha256 and rec["version"] == 1 and rec["stratum"] == stratum
        assert seed == session_seed(31, code)
        assert rec["traits"] == pytest.approx(person_traits(population, seed, stratum))
        # stored right after the session's plan (the same transaction that starts the session)
        kinds = [r[1] for r in rows if r[0] == sid]
        assert kinds[:2] == ["session_plan", "population"]
        assert any(all(p.get(k) == pytest.approx(v) for k, v in rec["traits"].items()) and p["hold_s"] == 0.3
                   for p in seen)
    assert not any(math.isclose(p.get("hold_s", 0.4), 0.4) for p in seen)


@pytest.mark.slow
def test_no_population_runs_as_before_and_says_so(tmp_path):
    from studyctl.populations import describe_choice
    from studyctl.protocol import load_protocol
    from studyctl.workflows.simulate import cohort_population, simulate_study

    proto = load_protocol(MINI_PROTOCOL)
    assert cohort_population(proto, "shipped") is None
    assert "none shipped for power_mini_palpation" in describe_choice(None, proto.study.id, False)
    result = simulate_study(MINI_PROTOCOL, 2, 31, tmp_path / "ws")
    assert result.population == ""
    con = sqlite3.connect(tmp_path / "ws" / "study.db")
    assert con.execute("select count(*) from event where kind = 'population'").fetchone()[0] == 0
    con.close()


def test_bad_population_writes_no_workspace(tmp_path):
    from studyctl.workflows.simulate import simulate_study

    bad = write_variant(tmp_path, "sd: 0.03", "sd: -1")
    with pytest.raises(PopulationError):
        simulate_study(MINI_PROTOCOL, 2, 31, tmp_path / "ws", population=bad)
    assert not (tmp_path / "ws").exists()


@pytest.mark.slow
def test_power_draws_people_from_the_population(tmp_path):
    from studyctl.power import prepare_power
    from studyctl.power.replicate import simulate_replicate

    spec = prepare_power(MINI_PROTOCOL, MINI_PLAN, sizes="4", replicates=1, seed=3, traits=POPULATION)
    bare = prepare_power(MINI_PROTOCOL, MINI_PLAN, sizes="4", replicates=1, seed=3)
    assert spec.traits is not None and bare.traits is None
    assert spec.fingerprint() != bare.fingerprint()
    tables = []
    simulate_replicate(spec, 4, 0, on_metrics=tables.append)
    simulate_replicate(bare, 4, 0, on_metrics=tables.append)
    times = [t.frame[t.frame["metric"] == "completion_time"]["value"].to_numpy() for t in tables]
    # the population's people are slower or faster than the default palpator: times differ person by person
    assert len(times[0]) == len(times[1]) and not np.allclose(times[0], times[1])


@pytest.mark.slow
def test_cli_simulate_names_the_population(tmp_path, capsys):
    from studyctl.cli.app import main

    code = main(["simulate", str(MINI_PROTOCOL), "-n", "2", "-s", "1", "-o", str(tmp_path / "w"),
                 "--population", str(POPULATION)])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "population: palpator_small v1 (given; sha256" in out.err
    bad = write_variant(tmp_path, "dist: lognormal", "dist: gamma")
    code = main(["simulate", str(MINI_PROTOCOL), "-n", "2", "-s", "1", "-o", str(tmp_path / "v"),
                 "--population", str(bad)])
    out = capsys.readouterr()
    assert code != 0 and "Traceback" not in out.err
    (line,) = [x for x in out.err.splitlines() if x.startswith("Error:")]
    assert f"{bad}:10:11: traits.press_speed_mm_s.dist: unknown distribution 'gamma'" in line
    assert not (tmp_path / "v").exists()


def test_a_resumed_session_rebuilds_the_same_person(tmp_path, monkeypatch, population):
    from studyctl.engine.api import resume_session, run_session, stored_population
    from studyctl.errors import SessionInterrupted
    from studyctl.store.workspace import open_study
    from studyctl.workflows.simulate import create_cohort

    cohort = create_cohort(MINI_PROTOCOL, 2, 9, tmp_path / "ws", population=population)
    seen = _params_seen(monkeypatch)

    def stop(participant, ui, rec):  # the session is stored (with its population event), then interrupted
        raise SessionInterrupted("stopped by the test")

    with open_study(None, cohort.workspace, cohort.study) as opened:
        with pytest.raises(SessionInterrupted):
            run_session(opened.store, cohort.codes[0], study=cohort.study, population=population, frontend=stop)
        (sess,) = opened.store.list_sessions(opened.store.get_participant(opened.study.id, cohort.codes[0]).id)
        stored = stored_population(opened.store, sess.id)
        first = dict(seen[-1])
        seen.clear()
        resume_session(opened.store, sess.id)
    assert stored["sha256"] == population.sha256
    assert seen and seen[0] == first  # the same person (fixed params and traits), not the plugin's defaults
    assert all(seen[0][k] == pytest.approx(v) for k, v in stored["traits"].items())
