"""Bad input is refused with one clear line before any simulation starts (and nothing is written)."""

from __future__ import annotations

import socket

import pytest
from power_testdata import PLAN, PROTOCOL

from studyctl.errors import ProtocolError, UsageError
from studyctl.power import prepare_power
from studyctl.power.spec import parse_memory, parse_sizes
from studyctl.workflows.power import run_power


def test_plan_of_another_protocol():
    with pytest.raises(UsageError, match=r"analyses protocol 'bio_inspired_palpation', but .* is protocol "
                                         r"'power_mini_palpation'"):
        prepare_power(PROTOCOL, "bio_inspired_palpation", sizes="4", replicates=1)


def test_plan_with_conditions_the_protocol_lacks(tmp_path):
    text = PLAN.read_text(encoding="utf-8").replace("- {id: linear, label: Linear}",
                                                    "- {id: linear, label: Linear}\n  - {id: bio, label: Bio}")
    bad = tmp_path / "plan.yaml"
    bad.write_text(text, encoding="utf-8")
    with pytest.raises(UsageError, match="condition 'bio' is not in protocol 'power_mini_palpation'"):
        prepare_power(PROTOCOL, bad, sizes="4", replicates=1)


def test_plan_reading_a_csv_file():
    with pytest.raises(UsageError, match="reads its data from a CSV file"):
        prepare_power("pseudo_haptic_palpation", "pseudo_haptic_palpation_published", sizes="8", replicates=1)


def test_sample_size_below_the_counterbalancing_sequences():
    # the shipped seed-000 protocol: Williams design for 4 conditions = 4 sequences
    with pytest.raises(UsageError, match=r"--participants 3: below the 4 counterbalancing sequences"):
        prepare_power("bio_inspired_palpation", "bio_inspired_palpation", sizes="3,8", replicates=1)
    with pytest.raises(UsageError, match="below the 2 counterbalancing sequences"):
        prepare_power(PROTOCOL, PLAN, sizes="1,4", replicates=1)


@pytest.mark.parametrize(("text", "message"), [("8,x", "'x' is not a whole number"), ("0,4", "at least 1"),
                                               ("4,4", "given twice"), ("", "at least one sample size")])
def test_sample_size_syntax(text, message):
    with pytest.raises(UsageError, match=message):
        parse_sizes(text)


def test_sizes_are_sorted_and_memory_parsed():
    assert parse_sizes("25, 8,12") == (8, 12, 25)
    assert parse_memory("2GiB") == 2 * 2**30 and parse_memory("1500MB") == 1_500_000_000
    assert parse_memory("0") is None
    with pytest.raises(UsageError, match="below 256 MiB"):
        parse_memory("10MB")
    with pytest.raises(UsageError, match="use a size like"):
        parse_memory("lots")


def test_replicates_and_seed_ranges():
    with pytest.raises(UsageError, match="--replicates"):
        prepare_power(PROTOCOL, PLAN, sizes="4", replicates=0)
    with pytest.raises(UsageError, match=r"--seed must be an integer in \[0, 2\*\*63\)"):
        prepare_power(PROTOCOL, PLAN, sizes="4", replicates=1, seed=-1)


def test_broken_protocol_names_file_and_line(tmp_path):
    bad = tmp_path / "p.yaml"
    bad.write_text(PROTOCOL.read_text(encoding="utf-8").replace("scheme: williams", "scheme: wiliams"),
                   encoding="utf-8")
    with pytest.raises(ProtocolError, match=r"p\.yaml:\d+"):
        prepare_power(bad, PLAN, sizes="4", replicates=1)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_scheduler_fails_before_anything_is_written(mini_spec, tmp_path):
    out = tmp_path / "report"
    pattern = r"cannot reach the Dask scheduler at 127\.0\.0\.1:\d+ \(.*\); start one with `dask scheduler`"
    with pytest.raises(UsageError, match=pattern):
        run_power(mini_spec, out, scheduler=f"127.0.0.1:{_closed_port()}")
    assert not out.exists()
    with pytest.raises(UsageError, match="expected HOST:PORT"):
        run_power(mini_spec, out, scheduler="tcp://nohost")


@pytest.mark.slow
def test_results_of_another_setup_are_not_mixed(mini_spec, serial_run):
    from dataclasses import replace

    other = replace(mini_spec, seed=mini_spec.seed + 1)
    with pytest.raises(UsageError, match=r"holds replicates of another setup \(different seed\)"):
        run_power(other, serial_run.out_dir, workers=0)
