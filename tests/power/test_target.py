"""--target: the smallest sample size reaching a target power, only among sizes that complete the blocks."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from power_testdata import PLAN, PROTOCOL, SEED, run_power_cli

from studyctl.errors import UsageError
from studyctl.power import prepare_power
from studyctl.power.target import allowed_sizes, check_target, completes_blocks, smallest_sizes
from studyctl.protocol import load_protocol, resolve_protocol


@pytest.mark.parametrize("bad", [0, 1, 0.0, 1.0, -0.2, 1.5, float("nan"), True])
def test_target_outside_zero_one_is_refused(bad):
    with pytest.raises(UsageError, match="strictly between 0 and 1"):
        check_target(bad)


def test_target_inside_is_kept():
    assert check_target(0.8) == 0.8 and check_target(None) is None


def test_blocks_follow_sequences_and_strata():
    mini = load_protocol(PROTOCOL)  # williams over 2 conditions, within 2 equal strata: blocks of 2 per stratum
    assert [n for n in range(1, 13) if completes_blocks(mini, n)] == [4, 8, 12]
    dd = load_protocol(resolve_protocol("data_driven_palpation"))  # williams AB/BA, one stratum
    assert completes_blocks(dd, 12) and not completes_blocks(dd, 13)
    ph = load_protocol(resolve_protocol("pseudo_haptic_palpation"))  # random orders: any size is balanced
    assert all(completes_blocks(ph, n) for n in (1, 7, 13))
    assert allowed_sizes(mini, 4, count=3) == [4, 8, 12]


def test_incomplete_block_is_one_clear_error():
    with pytest.raises(UsageError) as exc:
        prepare_power(PROTOCOL, PLAN, sizes="4,6", replicates=1, seed=SEED, target=0.8)
    msg = str(exc.value)
    assert "--participants 6" in msg and "allowed sizes start 4, 8, 12" in msg and "use e.g." in msg
    assert "\n" not in msg
    # without a target the old rule (at least one per sequence) still applies, so 6 is fine
    assert prepare_power(PROTOCOL, PLAN, sizes="4,6", replicates=1, seed=SEED).target is None


def _table(powers, reps=100):
    rows = []
    for n, (sig, lo, hi) in powers.items():
        rows.append({"participants": n, "test_id": "t", "test": "rank_sum", "kind": "two_sample", "metric": "m",
                     "split": "", "groups": "a vs b", "replicates": reps, "power": sig / reps,
                     "power_ci_low": lo, "power_ci_high": hi})
    return pd.DataFrame(rows)


def test_smallest_size_is_the_first_reaching_the_target():
    t = _table({8: (50, 0.4, 0.6), 12: (79, 0.7, 0.86), 16: (85, 0.77, 0.91), 20: (95, 0.89, 0.98)})
    rec = smallest_sizes(t, 0.8).to_records()[0]
    assert rec["participants"] == 16 and rec["reached"] and rec["power"] == 0.85
    assert (rec["power_ci_low"], rec["power_ci_high"]) == (0.77, 0.91)
    rec = smallest_sizes(t, 0.96).to_records()[0]
    assert rec["participants"] is None and not rec["reached"] and rec["largest_run"] == 20
    assert rec["power_at_largest"] == 0.95


@pytest.mark.slow
def test_cli_target_json_and_figure(tmp_path, capsys):
    out = tmp_path / "out"
    code, stdout, stderr = run_power_cli([PROTOCOL, "--plan", PLAN, "--participants", "4", "--replicates", "2",
                                          "--seed", SEED, "--workers", "0", "--out", out, "--target", "0.5",
                                          "--json"], capsys)
    assert code == 0, stderr
    doc = json.loads(stdout)
    assert doc["target"] == 0.5 and doc["sizes"] == [4]
    power = pd.DataFrame(doc["power"])
    for rec in doc["smallest_sizes"]:
        row = power[(power["test_id"] == rec["test_id"]) & (power["metric"] == rec["metric"])
                    & (power["split"] == rec["split"]) & (power["kind"] != "posthoc")].iloc[0]
        assert rec["reached"] == (row["power"] >= 0.5)
        if rec["reached"]:
            assert rec["participants"] == 4 and rec["power_ci_low"] == row["power_ci_low"]
    assert (out / "power_target.csv").is_file() and (out / "power_curve.png").is_file()


def test_cli_target_out_of_range_is_one_error_line(tmp_path, capsys):
    code, _, stderr = run_power_cli([PROTOCOL, "--plan", PLAN, "--participants", "4", "--replicates", "1",
                            "--out", tmp_path / "o", "--target", "1.2"], capsys)
    lines = [x for x in stderr.splitlines() if x.strip()]
    assert code != 0 and len(lines) == 1 and lines[0].startswith("Error: ") and "--target 1.2" in stderr
    assert not (tmp_path / "o").exists()


def test_figure_marks_the_smallest_size():
    from studyctl.report.power_figures import power_curve_figure

    t = _table({8: (50, 0.4, 0.6), 12: (85, 0.77, 0.91)})
    t["effect_size_name"] = ""
    target = smallest_sizes(t, 0.8).to_frame()
    fig = power_curve_figure(t, alpha=0.05, target=target, target_power=0.8)
    stars = [ln for ln in fig.axes[0].lines if ln.get_marker() == "*"]
    assert len(stars) == 1 and round(float(stars[0].get_xdata()[0])) == 12
    plain = power_curve_figure(t, alpha=0.05)
    assert not [ln for ln in plain.axes[0].lines if ln.get_marker() == "*"]


def test_factorial_terms_are_separate_tests():
    """An ART/LMM test gives one omnibus row per term in each replicate; each term's power stays within [0, 1]."""
    from studyctl.power.replicate import ROW_COLUMNS
    from studyctl.power.summary import summarise

    rows = []
    for r in range(3):
        for term, sig in (("group", r == 0), ("condition", True), ("group × condition", False)):
            rows.append((4, r, "art", "paper", "omnibus", "art_anova", "accuracy", "", term, "", 0.01, None, sig,
                         "", 0.1, "ok"))
    table = summarise(pd.DataFrame(rows, columns=list(ROW_COLUMNS)), (4,), 3).frame
    got = dict(zip(table["groups"], table["power"], strict=True))
    assert got == {"group": pytest.approx(1 / 3), "condition": 1.0, "group × condition": 0.0}
