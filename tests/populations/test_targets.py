"""Targets files: bad input names file:line and the nearest name; simulated statistics and agreement."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from population_testdata import DATA, MINI_PLAN, MINI_PROTOCOL, write_variant

from studyctl.calibration import agreement, distance, simulated_values
from studyctl.calibration.agreement import z_score
from studyctl.errors import PopulationError
from studyctl.populations.targets import Target, load_targets_file

TARGETS = DATA / "mini.targets.yaml"


def _load(path):
    from studyctl.analysis import load_plan
    from studyctl.protocol import load_protocol

    return load_targets_file(path, plan=load_plan(MINI_PLAN), protocol=load_protocol(MINI_PROTOCOL))


def test_loads_targets_with_roles_and_bands():
    ts = _load(TARGETS)
    assert [t.id for t in ts.by_role("fit")] == ["time_nofb_mean", "time_nofb_sd"]
    mean = ts.get("time_nofb_mean")
    assert mean.interval() == (17.0, 23.0) and mean.band() == "±1 published SD"  # ±1 published SD
    assert mean.published_se() == pytest.approx(3.0 / math.sqrt(8))
    assert ts.get("time_linear_mean").interval() == pytest.approx((22 - 1.96 * 1.2, 22 + 1.96 * 1.2))
    assert ts.get("accuracy_linear").interval() == (0.4, 0.8)
    line = next(i for i, x in enumerate(TARGETS.read_text().splitlines(), 1) if "id: kw_time_verdict" in x)
    assert ts.get("kw_time_verdict").value is False and ts.get("kw_time_verdict").location.endswith(f":{line}")


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("metric: accuracy", "metric: acuracy", r"metric 'acuracy' is not in plan .*did you mean 'accuracy'"),
        ("where: {condition: linear}\n    statistic: mean\n    value: 22.0",
         "where: {condition: linaer}\n    statistic: mean\n    value: 22.0", r"did you mean 'linear'"),
        ("statistic: sd", "statistic: stdev", r"unknown statistic 'stdev'"),
        ("uncertainty: {sd: 3.0, n: 8, basis: paper}", "uncertainty: {sd: -3.0, n: 8, basis: paper}",
         r"sd = -3 is negative"),
        ("{sd: 3.0, n: 8, basis: paper}", "{sd: 3.0, n: 8}", r"say what this sd is: basis: paper \| recomputed"),
        ("value: 0.6", "value: 1.6", r"a proportion|lies in"),
        ("role: validation\n    direction_vs", "role: check\n    direction_vs", r"role .check. must be fit or"),
        ("test: control_algorithm", "test: control_algoritm", r"did you mean 'control_algorithm'"),
        ("value: false", "value: 0.2", r"a verdict is true \(significant\) or false"),
        ("direction_vs: time_nofb_mean", "direction_vs: time_nofb_men", r"did you mean 'time_nofb_mean'"),
        ("uncertainty: {interval: [0.4, 0.8], basis: chosen}", "uncertainty: {interval: [0.8, 0.4], basis: chosen}",
         r"low ≤ high"),
        ("interval: [0.4, 0.8], basis: chosen", "interval: [0.4, 0.8]", r"say what this interval is: basis: paper"),
        ("basis: chosen", "basis: choosen", r"basis 'choosen' is not one of .*did you mean 'chosen'"),
        ("interval: [0.4, 0.8], basis: chosen", "interval: [0.4, 0.8], basis: wilson, n: 10",
         r"a wilson 95 % interval for 0.6 of n = 10 is \[0.313, 0.832\]"),
        ("format: studyctl-targets/1", "format: targets/2", r"format 'targets/2' is not supported"),
        ("value: false\n    role: validation", "value: false\n    p: 0.01\n    role: validation",
         r"p 0.01 contradicts value false: a non-significant verdict has p at or above alpha 0.05"),
        ("value: false\n    role: validation", "value: false\n    p: 7.1\n    role: validation",
         r"p 7.1 must be a p-value in \(0, 1\]"),
        ("value: 0.6", "value: 0.6\n    p: 0.2", r"p is the published p-value behind a verdict; a proportion"),
    ],
)
def test_bad_targets_name_file_line_and_fix(tmp_path, old, new, message):
    path = write_variant(tmp_path, old, new, source=TARGETS)
    with pytest.raises(PopulationError, match=message) as info:
        _load(path)
    text = str(info.value)
    assert text.startswith(f"{path}:") and text.split(":")[1].isdigit()
    assert "\n" not in text


def test_group_filter_must_be_a_stratum(tmp_path):
    path = write_variant(tmp_path, "where: {condition: no_feedback}\n    statistic: mean",
                         "where: {condition: no_feedback, group: expret}\n    statistic: mean", source=TARGETS)
    with pytest.raises(PopulationError, match=r"group 'expret' is not in protocol .*did you mean 'expert'"):
        _load(path)


def _table():
    # two people per condition: trial values chosen so every statistic is known by hand
    rows = []
    for person, cond, value in [("a", "no_feedback", 10.0), ("a", "no_feedback", 14.0), ("b", "no_feedback", 20.0),
                                ("a", "linear", 30.0), ("b", "linear", 50.0)]:
        rows.append({"participant": person, "group": "novice", "condition": cond, "trial": "1", "repetition": 1,
                     "metric": "completion_time", "level": None, "value": value, "denominator": math.nan})
    for person, hits in [("a", [1, 0]), ("b", [1, 1])]:
        for h in hits:
            rows.append({"participant": person, "group": "novice", "condition": "linear", "trial": "1",
                         "repetition": 1, "metric": "accuracy", "level": None, "value": float(h),
                         "denominator": 1.0})
    tests = pd.DataFrame([{"test_id": "control_algorithm", "kind": "omnibus", "metric": "completion_time",
                           "test": "kruskal_wallis", "split": None, "p": 0.2, "n": 4, "status": "ok",
                           "groups": "no_feedback, linear"}])
    return pd.DataFrame(rows), tests


def test_simulated_statistics_by_hand():
    ts = _load(TARGETS)
    frame, tests = _table()
    sim = simulated_values(ts.targets, frame, tests, alpha=0.05, rng=np.random.default_rng(0))
    assert sim.get("time_nofb_mean").value == pytest.approx((12.0 + 20.0) / 2)  # per-person means first
    assert sim.get("time_nofb_sd").value == pytest.approx(np.std([12.0, 20.0], ddof=1))
    assert sim.get("time_linear_mean").value == pytest.approx(40.0)
    assert sim.get("accuracy_linear").value == pytest.approx(0.75)
    assert sim.get("kw_time_verdict").value is False
    assert sim.get("time_nofb_mean").low <= 16.0 <= sim.get("time_nofb_mean").high


def test_agreement_and_distance():
    ts = _load(TARGETS)
    frame, tests = _table()
    sim = simulated_values(ts.targets, frame, tests, alpha=0.05, rng=np.random.default_rng(0))
    agr = agreement(ts.targets, sim, 0.05)
    rows = {r.target: r for r in agr.rows}
    assert rows["time_nofb_mean"].within is False  # 16 is outside the band [17, 23]
    assert rows["time_nofb_sd"].sd_ratio == pytest.approx(np.std([12.0, 20.0], ddof=1) / 3.0)
    assert rows["time_nofb_sd"].within is False  # ratio 1.89 > 1.5
    assert rows["time_linear_mean"].same_direction is True  # 40 > 16 as 22 > 20
    assert rows["accuracy_linear"].within is True
    assert rows["kw_time_verdict"].same_verdict is True
    summary = agr.summary()
    assert summary["validation"]["verdict_fraction"] == 1.0 and summary["fit"]["targets"] == 2
    total, z = distance(ts.by_role("fit"), sim, 0.05, {t.id: 0.0 for t in ts.targets})
    expected_z = (16.0 - 20.0) / (3.0 / math.sqrt(8))
    assert z["time_nofb_mean"] == pytest.approx(expected_z)
    assert total == pytest.approx(sum(v * v for v in z.values()))
    assert set(agr.to_frame().columns) >= {"published", "simulated", "same_direction", "within", "same_verdict",
                                          "role", "agrees"}


def test_a_verdicts_published_p_gives_how_often_a_replication_reproduces_it(tmp_path):
    """A verdict's ``p`` (and a test_p target's value) gives the agreement row's replication column: how often a
    same-size replication of the paper gives its verdict; the summary counts the verdicts with a p, those
    reproduced and the expected number."""
    from studyctl.calibration.replication import verdict_replication

    path = write_variant(tmp_path, "value: false\n    role: validation", "value: false\n    p: 0.071\n    role: "
                         "validation", source=TARGETS)
    ts = _load(path)
    assert ts.get("kw_time_verdict").published_p() == 0.071 and ts.get("time_nofb_mean").published_p() is None
    frame, tests = _table()
    sim = simulated_values(ts.targets, frame, tests, alpha=0.05, rng=np.random.default_rng(0))
    agr = agreement(ts.targets, sim, 0.05)
    rows = {r.target: r for r in agr.rows}
    assert rows["kw_time_verdict"].replication == pytest.approx(verdict_replication(0.071, 0.05, significant=False))
    # time_nofb_mean's band is ±1 SD with n = 8 (sampling SE 3/√8): a replication lands in it as often as
    # N(20, 2·SE²) falls in [17, 23]; accuracy_linear's band is CHOSEN, a tolerance with no such chance
    from studyctl.calibration.replication import band_replication

    assert rows["time_nofb_mean"].replication == pytest.approx(band_replication(20.0, 3.0 / math.sqrt(8), 17.0, 23.0))
    assert math.isnan(rows["accuracy_linear"].replication)
    s = agr.summary()["all"]
    assert (s["verdict_p_n"], s["verdict_p_reproduced"]) == (1, 1)
    assert s["verdict_expected"] == pytest.approx(rows["kw_time_verdict"].replication)
    # read back from agreement.csv as the bench and the seeds script do: the same counts
    back = pd.read_csv(pd.io.common.StringIO(agr.to_frame().to_csv(index=False)))
    from studyctl.calibration.agreement import checks_as_booleans, summary_from_frame

    assert summary_from_frame(checks_as_booleans(back))["all"]["verdict_expected"] == pytest.approx(
        s["verdict_expected"])


def test_a_p_value_is_compared_as_the_deviate_it_stands_for():
    """A p-value target's distance is the difference of the two normal deviates over a replication's SD √2, so a
    simulated effect larger than the paper's costs what its deviate says, not more the smaller p gets (the log10
    distance gave p 3.2e-6 against 0.034 a z of -8.1, 65 in z²)."""
    from scipy.stats import norm  # here, not at the top: importing scipy.stats costs test collection ~1 s

    target = Target("p", "scans", "test_p", 0.034, "validation", {}, test="scans_anova")
    strong = z_score(target, 3.2e-6, math.nan, 0.05)
    assert strong == pytest.approx((norm.isf(0.017) - norm.isf(1.6e-6)) / math.sqrt(2))
    assert -1.9 < strong < -1.7
    assert z_score(target, 0.034, math.nan, 0.05) == 0.0
    assert z_score(target, 0.5, math.nan, 0.05) > 0  # weaker evidence than the paper's: positive
    assert math.isfinite(z_score(target, 0.0, math.nan, 0.05))  # a p that underflowed to 0
    assert z_score(target, 1e-12, math.nan, 0.05) > z_score(target, 1e-20, math.nan, 0.05)


def test_cv_is_a_spread_judged_by_its_ratio():
    from studyctl.populations.targets import Target

    frame, tests = _table()
    cv = Target("cv_nofb", "completion_time", "cv", 0.3, "fit", {"condition": "no_feedback"}, {"n": 12})
    sim = simulated_values([cv], frame, tests, alpha=0.05, rng=np.random.default_rng(0))
    expected = np.std([12.0, 20.0], ddof=1) / 16.0
    assert sim.get("cv_nofb").value == pytest.approx(expected)
    (row,) = agreement([cv], sim, 0.05).rows
    assert row.sd_ratio == pytest.approx(expected / 0.3)
    assert row.within is bool(1 / 1.5 <= expected / 0.3 <= 1.5)
    assert cv.published_se() == pytest.approx(0.3 / math.sqrt(22))


PAIR_TARGETS = """format: studyctl-targets/1
protocol: pseudo_haptic_palpation
source: test
targets:
  - id: se_PHF_vs_FF
    metric: sensitivity
    statistic: verdict
    test: pairs_newcombe
    pair: [PHF, FF]
    value: true
    role: validation
  - id: time_PHF_FF_vs_FF
    metric: detection_time
    statistic: verdict
    test: time_signed_rank
    pair: [PHF_FF, FF]
    value: true
    role: validation
  - id: time_manual_PHF_FF_p
    metric: detection_time
    statistic: test_p
    test: time_signed_rank
    pair: [manual, PHF_FF]
    value: 0.3
    role: validation
"""


def _pair_tests() -> pd.DataFrame:
    """Result rows shaped as the plan's: Newcombe rows carry a verdict and no p; signed-rank rows carry a p."""
    def row(test_id, metric, test, groups, p, significant, statistic=1.0):
        return {"test_id": test_id, "kind": "pairwise", "metric": metric, "test": test, "split": "",
                "groups": groups, "p": p, "alpha": 0.05, "significant": significant, "statistic": statistic,
                "statistic_name": "W", "n": 40, "status": "ok"}

    return pd.DataFrame([
        row("pairs_newcombe", "sensitivity", "newcombe", "manual vs FF", math.nan, False),
        row("pairs_newcombe", "sensitivity", "newcombe", "FF vs PHF", math.nan, True, 0.28),
        row("time_signed_rank", "detection_time", "signed_rank", "manual vs FF", 0.001, None),
        row("time_signed_rank", "detection_time", "signed_rank", "manual vs PHF_FF", 0.3, None),
        row("time_signed_rank", "detection_time", "signed_rank", "FF vs PHF_FF", 0.2, None),
    ])


def test_pair_selects_the_pairwise_row_in_either_order(tmp_path):
    from studyctl.populations.targets import parse_targets

    ts = parse_targets(PAIR_TARGETS, "t.yaml")
    assert ts.get("se_PHF_vs_FF").pair == ("PHF", "FF")
    sim = simulated_values(ts.targets, pd.DataFrame(columns=["metric"]), _pair_tests(), alpha=0.05,
                           rng=np.random.default_rng(0))
    # Newcombe: the plan's own verdict (no p-value), for the row written "FF vs PHF"
    assert sim.get("se_PHF_vs_FF").value is True
    # signed rank FF vs PHF_FF: p = 0.2, not the first pair's p = 0.001
    assert sim.get("time_PHF_FF_vs_FF").value is False
    assert sim.get("time_manual_PHF_FF_p").value == pytest.approx(0.3)
    rows = {r.target: r for r in agreement(ts.targets, sim, 0.05).rows}
    assert rows["se_PHF_vs_FF"].same_verdict is True and rows["time_PHF_FF_vs_FF"].same_verdict is False
    assert rows["se_PHF_vs_FF"].where == "pair=PHF vs FF"
    # a pair the results do not hold is not computed (never another pair's row)
    missing = _pair_tests().query("groups != 'FF vs PHF'")
    sim2 = simulated_values(ts.targets, pd.DataFrame(columns=["metric"]), missing, alpha=0.05,
                            rng=np.random.default_rng(0))
    assert math.isnan(sim2.get("se_PHF_vs_FF").value) and "PHF vs FF" in sim2.get("se_PHF_vs_FF").note


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("pair: [PHF, FF]", "pair: [PFH, FF]", r"condition 'PFH' is not in the protocol; did you mean 'PHF'"),
        ("pair: [PHF, FF]", "pair: [PHF, PHF]", r"pair names two different levels"),
        ("pair: [PHF, FF]", "pair: PHF", r"pair names two different levels"),
        ("statistic: test_p", "statistic: mean", r"pair selects a pairwise test row; .* not a mean"),
    ],
)
def test_bad_pair_is_one_error_with_line_and_nearest_name(old, new, message):
    from studyctl.populations.targets import parse_targets

    text = PAIR_TARGETS.replace(old, new, 1)
    with pytest.raises(PopulationError, match=message) as info:
        parse_targets(text, "t.yaml")
    line = int(str(info.value).split(":")[1])
    assert "pair" in text.splitlines()[line - 1] or "statistic" in text.splitlines()[line - 1]


def _sensitivity(ff: float, phf: float, people: int = 6) -> pd.DataFrame:
    """Per-person sensitivity rows (3 nodules each) for FF and PHF."""
    rows = []
    for i in range(people):
        for cond, p in (("FF", ff), ("PHF", phf)):
            rows.append({"participant": f"P{i}", "group": "all", "condition": cond, "trial": 1,
                         "metric": "sensitivity", "level": None, "value": p, "denominator": 3.0})
    return pd.DataFrame(rows)


def test_a_significant_pair_the_wrong_way_does_not_reproduce_the_papers_verdict():
    """Regression (issue 17): a verdict-only pair target counted a significant result in the wrong direction as
    agreeing. With ``higher:`` (the paper's direction) it agrees only when significance and direction both match."""
    from studyctl.calibration.agreement import distance
    from studyctl.populations.targets import parse_targets

    text = PAIR_TARGETS.replace("    pair: [PHF, FF]\n", "    pair: [PHF, FF]\n    higher: FF\n", 1)
    ts = parse_targets(text, "t.yaml")
    target = ts.get("se_PHF_vs_FF")
    assert target.higher == "FF" and target.band() == "verdict and direction (FF > PHF)"
    assert ts.get("time_PHF_FF_vs_FF").band() == ""  # no direction stated: significance only, as before

    def row(metrics):
        sim = simulated_values(ts.targets, metrics, _pair_tests(), alpha=0.05, rng=np.random.default_rng(0))
        rows = {r.target: r for r in agreement(ts.targets, sim, 0.05).rows}
        return sim.get("se_PHF_vs_FF"), rows["se_PHF_vs_FF"], distance([target], sim, 0.05)[0]

    value, right, d_right = row(_sensitivity(ff=2 / 3, phf=1 / 3))  # FF higher, as the paper
    assert value.value is True and value.higher == "FF" and "FF higher" in value.note
    assert right.same_verdict is True and right.same_direction is True and right.agrees is True and d_right == 0
    value, wrong, d_wrong = row(_sensitivity(ff=1 / 3, phf=2 / 3))  # significant, but PHF higher
    assert value.value is True and value.higher == "PHF"
    assert wrong.same_verdict is False and wrong.same_direction is False and wrong.agrees is False
    assert d_wrong == pytest.approx(16.0)
    _, tied, _ = row(_sensitivity(ff=0.5, phf=0.5))  # no difference at all: no direction to credit
    assert tied.same_direction is False and tied.agrees is False
    # the same pair without a stated direction keeps the old, significance-only check
    plain = simulated_values(ts.targets, _sensitivity(ff=1 / 3, phf=2 / 3), _pair_tests(), alpha=0.05,
                             rng=np.random.default_rng(0))
    time_row = {r.target: r for r in agreement(ts.targets, plain, 0.05).rows}["time_PHF_FF_vs_FF"]
    assert time_row.same_direction is None
    # the simulated direction survives the journal's round trip
    from studyctl.calibration.simulated import stats_from_frame

    assert stats_from_frame(plain.to_frame()).get("se_PHF_vs_FF").higher == "PHF"


@pytest.mark.parametrize(
    ("insert", "message"),
    [
        ("    higher: PHX\n", r"higher 'PHX' is not in the pair \(PHF, FF\); did you mean 'PHF'"),
        ("    higher: 3\n", r"higher 3 is not in the pair"),
    ],
)
def test_bad_higher_is_one_error_with_line(insert, message):
    from studyctl.populations.targets import parse_targets

    text = PAIR_TARGETS.replace("    pair: [PHF, FF]\n", "    pair: [PHF, FF]\n" + insert, 1)
    with pytest.raises(PopulationError, match=message) as info:
        parse_targets(text, "t.yaml")
    line = int(str(info.value).split(":")[1])
    assert "higher" in text.splitlines()[line - 1]


def test_higher_needs_a_pair():
    from studyctl.populations.targets import parse_targets

    text = PAIR_TARGETS.replace("    pair: [manual, PHF_FF]\n", "    higher: manual\n", 1)
    with pytest.raises(PopulationError, match=r"higher states the direction of a pair target; give pair"):
        parse_targets(text, "t.yaml")


def test_a_pair_after_a_non_significant_omnibus_is_not_significant():
    """Post-hoc pairs run only after a significant omnibus test: without them the pair's verdict is 'not
    significant' (not a missing value); with a significant omnibus and no pair row it stays missing."""
    from studyctl.populations.targets import parse_targets

    text = """format: studyctl-targets/1
protocol: bio_inspired_palpation
source: test
targets:
  - id: force_linear_vs_bio
    metric: mean_force
    statistic: verdict
    test: control_algorithm
    pair: [linear, bio_inspired]
    higher: linear
    value: true
    role: validation
"""
    ts = parse_targets(text, "t.yaml")
    omnibus = pd.DataFrame([{"test_id": "control_algorithm", "kind": "omnibus", "metric": "mean_force",
                             "test": "kruskal_wallis", "compare": "condition", "split": "",
                             "groups": "no_feedback, piecewise, linear, bio_inspired", "p": 0.4, "alpha": 0.05,
                             "significant": False, "n": 100, "status": "ok"}])
    sim = simulated_values(ts.targets, pd.DataFrame(columns=["metric"]), omnibus, alpha=0.05,
                           rng=np.random.default_rng(0))
    v = sim.get("force_linear_vs_bio")
    assert v.value is False and "omnibus kruskal_wallis is not significant" in v.note
    (row,) = agreement(ts.targets, sim, 0.05).rows
    assert row.same_verdict is False and row.band == "verdict and direction (linear > bio_inspired)"
    significant = omnibus.assign(p=0.001, significant=True)
    sim = simulated_values(ts.targets, pd.DataFrame(columns=["metric"]), significant, alpha=0.05,
                           rng=np.random.default_rng(0))
    assert math.isnan(sim.get("force_linear_vs_bio").value)


def test_the_simulated_direction_of_a_pair_of_tumour_classes():
    """A pair of a metric's own levels (tumour classes) is read from the level column, per person."""
    from studyctl.calibration.simulated import _higher
    from studyctl.populations.targets import Target

    t = Target("c", "detection", "verdict", True, "validation", {"condition": "no_feedback"}, test="tumour_class",
               pair=("soft", "hard"), higher="hard")
    rows = [{"participant": f"P{i}", "group": "novice", "condition": cond, "trial": 1, "metric": "detection",
             "level": lv, "value": float(v), "denominator": 1.0}
            for i in range(5) for cond, soft in (("no_feedback", 0), ("linear", 1))
            for lv, v in (("soft", soft), ("hard", 1 - soft if cond == "linear" else 1))]
    frame = pd.DataFrame(rows)
    assert _higher(frame, t, "tumour_class") == "hard"  # only the target's condition counts
    assert _higher(frame, t, "") == "hard"  # a row that does not name its factor: the column holding both levels
    assert _higher(frame.assign(value=1.0), t, "tumour_class") == ""  # tied
