"""``studyctl protocol show|schedule`` and ``studyctl bench schedule``."""

from __future__ import annotations

import csv
import io
import json

import pytest

from studyctl.bench.schedule import run as bench_run
from studyctl.cli.app import main
from studyctl.protocol.schedule import SCHEDULE_ALGORITHM_VERSION

SHIPPED = ["bio_inspired_palpation", "needle_insertion", "data_driven_palpation", "pseudo_haptic_palpation"]


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_protocols_check_and_show(name, capsys):
    assert main(["protocol", "check", name]) == 0
    assert capsys.readouterr().out.startswith("OK: ")
    assert main(["protocol", "show", name]) == 0
    out = capsys.readouterr().out
    assert "Conditions (" in out and "Counterbalancing:" in out and "Resume: interrupted trial" in out


def test_show_needle_insertion_lists_orders_and_questionnaires(capsys):
    assert main(["protocol", "show", "needle_insertion"]) == 0
    out = capsys.readouterr().out
    assert "      1: BL → RT → ES → EG → ESG" in out
    assert "      2: BL → ESG → EG → ES → RT" in out
    assert "allocation blocked (6 per sequence)" in out
    assert "time limit 90 s" in out
    assert "scenario_experience v2024.1: 3 item(s), after condition (conditions RT, ES, EG, ESG)" in out


def test_schedule_csv_rows(capsys):
    assert main(["protocol", "schedule", "needle_insertion", "--participants", "12", "--seed", "4",
                 "--format", "csv"]) == 0
    captured = capsys.readouterr()
    rows = list(csv.DictReader(io.StringIO(captured.out)))
    assert len(rows) == 12 * 15
    assert list(rows[0]) == ["participant", "stratum", "slot", "trial", "position", "block", "condition",
                             "repetition", "placement", "orientation_deg"]
    order_of = {}
    for row in rows:
        if row["repetition"] == "1":
            order_of.setdefault(int(row["participant"]), []).append(row["condition"])
    assert order_of[1] == ["BL", "RT", "ES", "EG", "ESG"] and order_of[7] == ["BL", "ESG", "EG", "ES", "RT"]
    assert "position_spread" in captured.err  # diagnostics go to stderr, rows stay parseable


def test_schedule_json_with_balance(capsys):
    assert main(["protocol", "schedule", "bio_inspired_palpation", "-n", "16", "--format", "json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["protocol"] == "bio_inspired_palpation" and data["seed"] == 134
    assert data["algorithm_version"] == SCHEDULE_ALGORITHM_VERSION
    assert len(data["rows"]) == 16 * 4
    assert {r["stratum"] for r in data["rows"]} == {"novice", "expert"}
    assert all(r["placement"].count("=") == 3 for r in data["rows"])
    summary = {s["stratum"]: s for s in data["balance"]["summary"]}
    # 16 participants over 15:10 targets → 10 novices and 6 experts: neither a multiple of 4
    assert summary["novice"]["participants"] == 10 and summary["expert"]["participants"] == 6
    counts = [c for c in data["balance"]["counts"] if c["kind"] == "position" and c["stratum"] == "novice"]
    assert sum(c["count"] for c in counts) == 10 * 4


def test_schedule_table_shows_diagnostics(capsys):
    assert main(["protocol", "schedule", "data_driven_palpation", "-n", "4", "-s", "1"]) == 0
    out = capsys.readouterr().out
    assert "position counts (condition × position):" in out
    assert "carry-over counts (row followed by column):" in out
    assert out.rstrip().endswith("(spread = max − min count over the counterbalanced conditions; 0 is perfectly "
                                 "balanced)")


def test_schedule_needs_a_seed(tmp_path, valid_text, capsys):
    path = tmp_path / "noseed.yaml"
    path.write_text(valid_text.replace("  seed: 7\n", ""), encoding="utf-8")
    assert main(["protocol", "schedule", str(path), "-n", "2"]) == 2
    assert capsys.readouterr().err.strip() == "Error: no seed: pass --seed S or set study.seed in the protocol"


def test_unknown_protocol_name(capsys):
    assert main(["protocol", "check", "no_such_protocol"]) != 0
    err = capsys.readouterr().err
    assert err.startswith("Error: no file 'no_such_protocol' and no shipped protocol of that name; shipped: ")


@pytest.mark.slow
def test_bench_schedule_quick_reports_figures():
    result = bench_run(quick=True)
    assert result.name == "schedule"
    assert result.figures["participants_per_s"] > 0
    assert {f"participants_per_s_{name}" for name in SHIPPED} <= set(result.figures)
    assert [row["protocol"] for row in result.tables["protocols"]] == SHIPPED
    assert result.tables["protocols"][1]["trials"] == 1_000 * 15
