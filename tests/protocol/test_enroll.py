"""Enrollment: next slot within the stratum, withdrawn slots reused, unique codes under concurrency."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import time
from collections import Counter

import pytest
from sqlalchemy import update

from studyctl.cli.app import main
from studyctl.errors import IntegrityError, UsageError
from studyctl.protocol import expand_schedule, load_protocol_text
from studyctl.store import StudyStore
from studyctl.store.enrollment import CODE_ALPHABET, enroll, new_code, next_slot, replan
from studyctl.store.models import Participant
from studyctl.store.workspace import init_workspace


def _study(store: StudyStore, text: str, seed: int = 42):
    return store.create_study("mini", protocol_text=text, protocol_name="mini", seed=seed)


@pytest.fixture
def replacing(valid_text) -> str:
    return valid_text.replace("participants:\n", "participants:\n  replace_withdrawn: true\n", 1)


def test_next_slot_rules():
    taken = [(0, "completed"), (1, "withdrawn"), (2, "active")]
    assert next_slot(taken, replace_withdrawn=False) == 3
    assert next_slot(taken, replace_withdrawn=True) == 1
    assert next_slot([], replace_withdrawn=True) == 0
    assert next_slot([(0, "withdrawn"), (1, "withdrawn")], replace_withdrawn=True) == 0


def test_codes_are_random_and_avoid_taken_ones():
    draws = iter("AAAAA" "AAAAA" "BCDEF")
    code = new_code("P", {"P-AAAAA"}, token=lambda alphabet: next(draws))
    assert code == "P-BCDEF"
    assert all(ch in CODE_ALPHABET for ch in new_code("NDL", set())[4:])


def test_enroll_sequence_and_stored_plan(sqlite_store, valid_text):
    study = _study(sqlite_store, valid_text)
    got = [enroll(sqlite_store, g) for g in ("novice", "novice", "expert", "novice")]
    assert [(e.stratum, e.slot) for e in got] == [("novice", 0), ("novice", 1), ("expert", 0), ("novice", 2)]
    assert len({e.code for e in got}) == 4 and all(e.code.startswith("P-") for e in got)
    protocol = load_protocol_text(valid_text, "mini")
    for e in got:
        assert e.schedule == expand_schedule(protocol, seed=42, slot=e.slot, stratum=e.stratum)
    stored = sqlite_store.list_participants(study.id)
    assert [p.code for p in stored] == [e.code for e in got]
    for p in stored:
        assert p.schedule_seed == 42 and p.schedule_algorithm_version == "1"
        assert replan(protocol, p).to_json() == p.schedule
    assert got[0].to_frame().columns[:3].tolist() == ["code", "stratum", "trial"]


def test_withdrawn_slot_goes_to_next_enrollee(sqlite_store, replacing):
    _study(sqlite_store, replacing)
    first, second, _ = (enroll(sqlite_store, "novice") for _ in range(3))
    sqlite_store.set_participant_status(second.participant_id, "withdrawn", reason="left")
    sqlite_store.set_participant_status(first.participant_id, "completed")
    replacement = enroll(sqlite_store, "novice")
    assert replacement.slot == second.slot == 1
    assert replacement.order == second.order
    assert enroll(sqlite_store, "novice").slot == 3


def test_without_replacement_every_assignment_counts(sqlite_store, valid_text):
    _study(sqlite_store, valid_text)
    a, b = enroll(sqlite_store, "expert"), enroll(sqlite_store, "expert")
    sqlite_store.set_participant_status(a.participant_id, "withdrawn")
    assert enroll(sqlite_store, "expert").slot == 2
    assert b.slot == 1


def test_enroll_errors(sqlite_store, valid_text):
    study = _study(sqlite_store, valid_text)
    with pytest.raises(UsageError, match="this study has groups novice, expert; say which with --group"):
        enroll(sqlite_store)
    with pytest.raises(UsageError, match=r"unknown group 'expret'; this study has novice, expert \(did you mean "
                                         r"'expert'\?\)"):
        enroll(sqlite_store, "expret")
    e = enroll(sqlite_store, "novice", code="P-FIXED")
    assert e.code == "P-FIXED"
    with pytest.raises(UsageError, match="participant code 'P-FIXED' is already enrolled"):
        enroll(sqlite_store, "novice", code="P-FIXED")
    # an edited stored plan is detected on re-expansion
    with sqlite_store.in_transaction() as tx:
        tx.execute(update(Participant).where(Participant.code == "P-FIXED").values(schedule={"entries": []}))
    participant = sqlite_store.get_participant(study.id, "P-FIXED")
    with pytest.raises(IntegrityError, match="stored plan of participant P-FIXED differs"):
        replan(load_protocol_text(valid_text, "mini"), participant)


def test_study_without_protocol_cannot_enroll(sqlite_store):
    sqlite_store.create_study("bare", seed=1)
    with pytest.raises(UsageError, match="has no protocol"):
        enroll(sqlite_store, "novice")


WORKER = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from studyctl.store import StudyStore
    from studyctl.store.enrollment import enroll
    url, go, n, first = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    store = StudyStore.open(url)
    deadline = time.monotonic() + 60
    while not go.exists() and time.monotonic() < deadline:
        time.sleep(0.002)
    groups = ["novice", "expert"]
    for i in range(n):
        e = enroll(store, groups[(first + i) % 2], over_target=True)  # 18 enrollments race past the targets
        print(e.code, e.stratum, e.slot, flush=True)
    store.close()
    """
)


@pytest.mark.slow
def test_concurrent_enrollers_never_share_code_or_slot(db_url, valid_text, tmp_path):
    """Three processes enroll at the same moment, on SQLite and on PostgreSQL."""
    with StudyStore.open(db_url) as store:
        _study(store, valid_text.replace("participants:\n", "participants:\n  code_prefix: C\n", 1))
    go = tmp_path / "go"
    workers, per_worker = 3, 6
    procs = [
        subprocess.Popen([sys.executable, "-c", WORKER, db_url, str(go), str(per_worker), str(w)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for w in range(workers)
    ]
    time.sleep(0.5)
    go.touch()
    lines = []
    for proc in procs:
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        lines += out.split("\n")
    rows = [line.split() for line in lines if line.strip()]
    assert len(rows) == workers * per_worker
    codes = [r[0] for r in rows]
    assert len(set(codes)) == len(codes)
    by_stratum = Counter(r[1] for r in rows)
    for stratum, count in by_stratum.items():
        slots = sorted(int(r[2]) for r in rows if r[1] == stratum)
        assert slots == list(range(count)), f"{stratum}: {slots}"
    with StudyStore.open(db_url) as store:
        stored = store.list_participants(store.get_study("mini").id)
    assert sorted(p.code for p in stored) == sorted(codes)
    assert len({(p.stratum, p.sequence_slot) for p in stored}) == len(stored)


def test_cli_enroll(tmp_path, capsys, valid_text):
    proto = tmp_path / "mini.yaml"
    proto.write_text(valid_text, encoding="utf-8")
    init_workspace(tmp_path / "ws", protocol=str(proto), seed=9)
    capsys.readouterr()
    assert main(["enroll", "-w", str(tmp_path / "ws"), "--group", "expert"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("Enrolled P-") and out[0].endswith("in group expert: slot 1, sequence 1")
    assert out[1] == "  order: A → B → D → C"
    assert out[2].startswith("  trial   1: A (block 1, repetition 1); placement soft=")
    # --json counts as the text does, in fields named by their base; the stored plan's indices count from 0
    assert main(["enroll", "-w", str(tmp_path / "ws"), "--group", "expert", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    plan = got["schedule"]
    assert (got["slot_number"], got["slot_index"], plan["slot"]) == (2, 1, 1)
    assert got["sequence_number"] == got["sequence_index"] + 1 == plan["sequence"] + 1
    assert main(["enroll", "-w", str(tmp_path / "ws"), "--group", "expert"]) == 0
    assert capsys.readouterr().out.splitlines()[0].endswith(f"slot 3, sequence {got['sequence_number'] + 1}")
    assert main(["enroll", "-w", str(tmp_path / "ws")]) == 2
    assert capsys.readouterr().err.strip() == ("Error: this study has groups novice, expert; say which with "
                                               "--group")
