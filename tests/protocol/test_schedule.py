"""Schedule expansion: deterministic plans, balance across complete sets, placements, orientations."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from studyctl.errors import UsageError
from studyctl.protocol import (
    SCHEDULE_ALGORITHM_VERSION,
    Planner,
    Schedule,
    allocate_strata,
    expand_many,
    expand_schedule,
    load_protocol,
    load_protocol_text,
    resolve_protocol,
    schedule_balance,
    schedule_rows,
)
from studyctl.protocol.stored_plan import PLAN_COLUMNS


@pytest.fixture
def mini(valid_text):
    return load_protocol_text(valid_text, "mini.yaml")


def _variant(valid_text, old, new):
    assert old in valid_text
    return load_protocol_text(valid_text.replace(old, new, 1), "variant.yaml")


def test_expanding_again_gives_the_identical_plan(mini, valid_text):
    a = expand_schedule(mini, seed=11, slot=3, stratum="novice")
    b = expand_schedule(load_protocol_text(valid_text, "again.yaml"), seed=11, slot=3, stratum="novice")
    assert a == b
    assert a.to_json() == b.to_json()
    assert a.algorithm_version == SCHEDULE_ALGORITHM_VERSION
    assert a.protocol_sha256 == mini.sha256 and a.seed == 11 and a.slot == 3
    assert Schedule.from_json(a.to_json()) == a


def test_plan_is_pinned(mini):
    # A change here changes every stored plan: bump SCHEDULE_ALGORITHM_VERSION with it.
    s = expand_schedule(mini, seed=11, slot=3, stratum="novice")
    assert s.order == ("D", "A", "C", "B")
    assert [e.placement for e in s.entries] == [
        (("soft", 4), ("medium", 5), ("hard", 1)),
        (("soft", 7), ("medium", 2), ("hard", 4)),
        (("soft", 3), ("medium", 4), ("hard", 1)),
        (("soft", 2), ("medium", 7), ("hard", 4)),
    ]


def test_different_slots_and_seeds_differ(mini):
    base = expand_schedule(mini, seed=11, slot=3, stratum="novice")
    assert expand_schedule(mini, seed=12, slot=3, stratum="novice").entries != base.entries
    assert expand_schedule(mini, seed=11, slot=4, stratum="novice").order != base.order
    # strata have their own slots and streams
    assert expand_schedule(mini, seed=11, slot=3, stratum="expert").entries != base.entries


def test_plan_fields(mini):
    s = expand_schedule(mini, seed=1, slot=0, stratum="expert")
    assert [e.trial for e in s.entries] == [1, 2, 3, 4]
    assert [e.position for e in s.entries] == [1, 2, 3, 4]
    assert [e.break_before_s for e in s.entries] == [0.0, 30.0, 30.0, 30.0]
    assert all(e.time_limit_s == 60 for e in s.entries)
    assert all(e.questionnaires_after == ("likert",) for e in s.entries)
    assert s.order == ("A", "B", "D", "C")  # Williams row 0 of 4 conditions
    frame = s.to_frame()
    assert list(frame.columns) == list(PLAN_COLUMNS)
    assert frame["placement"].iloc[0].count("=") == 3
    assert s.entries[0].scene_placement()["sites"] == s.entries[0].placement_map


def test_complete_sets_balance_positions_and_carryover(mini):
    schedules = [expand_schedule(mini, seed=5, slot=k, stratum=st) for st in ("novice", "expert") for k in range(8)]
    report = schedule_balance(mini, schedules)
    assert report.participants == (8, 8)
    assert report.position_spread == (0, 0)
    assert report.carryover_spread == (0, 0)
    assert report.position_counts[0].tolist() == [[2] * 4] * 4


@given(seed=st.integers(0, 2**40), slot=st.integers(0, 10_000))
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_every_tumour_moves_every_trial(valid_text, seed, slot):
    protocol = load_protocol_text(valid_text, "mini.yaml")
    s = expand_schedule(protocol, seed=seed, slot=slot, stratum="novice")
    previous = None
    for e in s.entries:
        sites = [site for _, site in e.placement]
        assert [item for item, _ in e.placement] == ["soft", "medium", "hard"]
        assert len(set(sites)) == 3 and all(1 <= x <= 7 for x in sites)
        if previous is not None:
            assert all(a != b for a, b in zip(sites, previous, strict=True))
        previous = sites


@given(seed=st.integers(0, 2**40))
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_assignment_rule_never_repeats_previous_placement(valid_text, seed):
    protocol = _variant(valid_text, "sites: 7, items: [soft, medium, hard], differ_from_previous: every_item",
                        "sites: 3, items: [soft, medium], differ_from_previous: assignment")
    placements = [e.placement for e in expand_schedule(protocol, seed=seed, slot=0, stratum="novice").entries]
    assert all(a != b for a, b in zip(placements, placements[1:], strict=False))


def test_blocked_and_shuffled_allocation(valid_text):
    blocked = _variant(valid_text, "  scheme: williams",
                       "  scheme: cyclic_latin\n  allocation: blocked\n  block_size: 3")
    planner = Planner(blocked)
    assert [planner.sequence_index(1, "novice", k) for k in range(14)] == [0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3, 0, 0]
    shuffled = _variant(valid_text, "  scheme: williams", "  scheme: williams\n  allocation: shuffled")
    planner = Planner(shuffled)
    got = [planner.sequence_index(9, "novice", k) for k in range(12)]
    for start in range(0, 12, 4):
        assert sorted(got[start:start + 4]) == [0, 1, 2, 3]
    assert got != list(range(4)) * 3  # shuffled, not rotated (for this seed)
    assert got == [planner.sequence_index(9, "novice", k) for k in range(12)]


def test_blocks_repetitions_and_questionnaire_points(valid_text):
    text = valid_text.replace("  scheme: williams", "  scheme: cyclic_latin")
    text = text.replace("trial:\n", "design: {repetitions: 2, blocks: 2, block_order: reverse}\ntrial:\n")
    text = text.replace("  break_s: 30", "  break_s: 30\n  break_between: conditions\n"
                        "  familiarisation: {max_s: 120, when: before_each_condition}")
    text = text.replace("  - {instrument: likert, when: after_condition}",
                        "  - {instrument: likert, when: after_block}\n  - {instrument: likert, when: start}")
    protocol = load_protocol_text(text, "blocks.yaml")
    s = expand_schedule(protocol, seed=3, slot=1, stratum="novice")
    assert len(s.entries) == 4 * 2 * 2
    block1 = [e.condition for e in s.entries if e.block == 1]
    block2 = [e.condition for e in s.entries if e.block == 2]
    assert block1 == ["B", "B", "C", "C", "D", "D", "A", "A"]
    assert block2 == block1[::-1]
    assert [e.repetition for e in s.entries[:4]] == [1, 2, 1, 2]
    assert [e.break_before_s for e in s.entries[:4]] == [0.0, 0.0, 30.0, 0.0]
    assert [e.familiarisation_max_s for e in s.entries[:4]] == [120.0, None, 120.0, None]
    assert [e.trial for e in s.entries if e.questionnaires_after] == [8, 16]
    assert s.questionnaires_start == ("likert",)


def test_orientation_per_condition_always_changes(valid_text):
    text = valid_text.replace("  placement: {sites: 7, items: [soft, medium, hard], differ_from_previous: every_item}",
                              "  orientation: {choices_deg: [0, 90], per: condition, differ_from_previous: true}")
    text = text.replace("trial:\n", "design: {repetitions: 3}\ntrial:\n")
    protocol = load_protocol_text(text, "orient.yaml")
    for slot in range(20):
        s = expand_schedule(protocol, seed=2, slot=slot, stratum="expert")
        angles = [e.orientation_deg for e in s.entries]
        per_condition = angles[::3]
        assert all(angles[i] == angles[i - i % 3] for i in range(len(angles)))  # constant within a condition
        assert all(a != b for a, b in zip(per_condition, per_condition[1:], strict=False))
        assert set(angles) <= {0.0, 90.0}
        assert all(e.placement is None for e in s.entries)


def test_bad_arguments(mini):
    with pytest.raises(UsageError, match="this protocol has strata novice, expert; say which one"):
        expand_schedule(mini, seed=1, slot=0)
    with pytest.raises(UsageError, match="unknown stratum 'nov'"):
        expand_schedule(mini, seed=1, slot=0, stratum="nov")
    with pytest.raises(UsageError, match="slot must be a non-negative integer"):
        expand_schedule(mini, seed=1, slot=-1, stratum="novice")
    with pytest.raises(UsageError, match="seed must be a non-negative integer"):
        expand_schedule(mini, seed=-3, slot=0, stratum="novice")


def test_allocate_strata_by_target(mini):
    assert allocate_strata(mini, 5) == [("novice", 0), ("novice", 1), ("novice", 2), ("expert", 0), ("expert", 1)]
    rows = schedule_rows(expand_many(mini, seed=1, participants=3))
    assert list(rows.columns) == ["participant", "stratum", "slot", "trial", "position", "block", "condition",
                                  "repetition", "placement", "orientation_deg"]
    assert rows["participant"].tolist() == [1] * 4 + [2] * 4 + [3] * 4
    # 1-based within each stratum, as `studyctl enroll` prints it
    assert rows.groupby("participant").first()[["stratum", "slot"]].values.tolist() == [
        ["novice", 1], ["novice", 2], ["expert", 1]]


@pytest.mark.parametrize("name", ["bio_inspired_palpation", "needle_insertion", "data_driven_palpation",
                                  "pseudo_haptic_palpation"])
def test_batch_expansion_equals_one_by_one(name):
    protocol = load_protocol(resolve_protocol(name))
    pairs = allocate_strata(protocol, 60)
    planner = Planner(protocol)
    assert planner.expand_batch(seed=17, pairs=pairs) == [
        Planner(protocol).expand(seed=17, slot=slot, stratum=stratum) for stratum, slot in pairs
    ]


def test_batch_expansion_with_scarce_candidates(valid_text):
    # 2 sites, 2 items, every item moves: only the swap is accepted, so most batches run dry
    protocol = _variant(valid_text, "sites: 7, items: [soft, medium, hard], differ_from_previous: every_item",
                        "sites: 2, items: [soft, medium], differ_from_previous: every_item")
    protocol = _variant(protocol.source_text, "  scheme: williams", "  scheme: williams\ndesign: {repetitions: 9}")
    pairs = [("novice", k) for k in range(10)]
    batch = Planner(protocol).expand_batch(seed=5, pairs=pairs)
    assert batch == [expand_schedule(protocol, seed=5, slot=k, stratum="novice") for _, k in pairs]
    sites = [e.placement_map["soft"] for e in batch[0].entries]
    assert len(sites) == 36 and all(a != b for a, b in zip(sites, sites[1:], strict=False))


def test_counterbalancing_across_strata(valid_text):
    protocol = _variant(valid_text, "  scheme: williams", "  scheme: williams\n  within_strata: false")
    assert allocate_strata(protocol, 4) == [("novice", 0), ("novice", 1), ("expert", 2), ("expert", 3)]
    a = expand_schedule(protocol, seed=1, slot=2, stratum="novice")
    b = expand_schedule(protocol, seed=1, slot=2, stratum="expert")
    assert a.entries == b.entries and a.stratum != b.stratum
    orders = [s.order for s in expand_many(protocol, seed=1, participants=4)]
    assert len(set(orders)) == 4


# ---------------------------------------------------------------------------- reference protocols


def _shipped(name):
    return load_protocol(resolve_protocol(name))


def test_needle_insertion_orders_match_the_paper():
    p = _shipped("needle_insertion")
    first = ("BL", "RT", "ES", "EG", "ESG")
    second = ("BL", "ESG", "EG", "ES", "RT")
    orders = [expand_schedule(p, seed=p.study.seed, slot=k).order for k in range(13)]
    assert orders == [first] * 6 + [second] * 6 + [first]
    s = expand_schedule(p, seed=p.study.seed, slot=0)
    assert len(s.entries) == 15 and [e.repetition for e in s.entries[:3]] == [1, 2, 3]
    assert all(e.time_limit_s == 90 for e in s.entries)
    assert [e.familiarisation_max_s for e in s.entries].count(900.0) == 1
    after = {e.trial: e.questionnaires_after for e in s.entries if e.questionnaires_after}
    assert after == {6: ("scenario_experience",), 9: ("scenario_experience",), 12: ("scenario_experience",),
                     15: ("scenario_experience", "end_of_study")}
    assert p.condition("RT").visual == "realtime"
    assert {p.condition(c).visual for c in ("BL", "ES", "EG", "ESG")} == {"on_request"}
    # Table 1 parameters
    assert p.condition("ES").params["tumour"] == {"k_stiff": 1000, "k_cut": 10, "f_dynamic": 1.4, "f_static": 1.8,
                                                  "c": 15}
    assert [p.condition(c).params["radial"]["k_d"] for c in first] == [30, 30, 30, 70, 50]
    assert [p.condition(c).params["radial"]["k_p"] for c in first] == [100, 100, 100, 1000, 1000]
    scale = p.instrument("scenario_experience").scale
    assert scale.points == 5 and scale.anchors[5] == "Strongly agree" and scale.codes == (1, 2, 3, 4, 5)
    assert p.resume.interrupted_trial == "invalidate_and_append"


def test_bio_inspired_palpation_is_williams_within_strata():
    p = _shipped("bio_inspired_palpation")
    assert p.stratum_ids == ("novice", "expert")
    schedules = [expand_schedule(p, seed=p.study.seed, slot=k, stratum=s) for s in p.stratum_ids for k in range(8)]
    report = schedule_balance(p, schedules)
    assert report.position_spread == (0, 0) and report.carryover_spread == (0, 0)
    s = schedules[0]
    assert [e.familiarisation_max_s for e in s.entries] == [300.0] * 4
    assert [e.break_before_s for e in s.entries] == [0.0, 30.0, 30.0, 30.0]
    assert p.trial.report.kind == "grid_cell" and p.trial.report.hit_radius == 1
    assert p.scene.placement.sites == 7 and p.scene.placement.items == ["soft", "medium", "hard"]


def test_data_driven_palpation_is_ab_ba():
    p = _shipped("data_driven_palpation")
    orders = [expand_schedule(p, seed=2, slot=k).order for k in range(4)]
    assert orders == [("manual", "haptic"), ("haptic", "manual")] * 2
    assert p.condition("manual").manual and p.condition("manual").controller is None
    assert p.condition("haptic").controller == "stiffness_map_ff"


def test_pseudo_haptic_palpation_random_orders_and_orientations():
    p = _shipped("pseudo_haptic_palpation")
    schedules = [expand_schedule(p, seed=3, slot=k) for k in range(40)]
    orders = {s.order for s in schedules}
    assert len(orders) > 10
    assert all(sorted(o) == sorted(p.condition_ids) for o in orders)
    assert all(s.sequence is None for s in schedules)
    for s in schedules:
        angles = [e.orientation_deg for e in s.entries]
        assert all(a != b for a, b in zip(angles, angles[1:], strict=False))
    assert p.instrument("combined_vs_ff").scale.points == 2
