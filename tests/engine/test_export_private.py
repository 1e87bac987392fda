"""Exports are private like the database (0600 files, 0700 folder) and carry no host or pid unless asked."""

from __future__ import annotations

import csv
import io
import json
import stat

from studyctl.cli.app import main
from studyctl.store.workspace import open_study

HOST, PID = "lab-pc-7f3a9e", 987654321


def test_export_files_are_private_and_anonymous(tmp_path, capsys, scripted_person_study):
    ws = scripted_person_study
    with open_study(workspace=ws) as o:
        # what older studyctl versions stored with every session start and resume
        # (a distinctive host and pid: this VM's host name "vm" and a pid like 4242 also occur inside timestamps and
        # payload text, which made a substring check fail at random)
        o.store.append_event(1, "session_process", {"pid": PID, "host": HOST}, t_mono=0.0)
    out = tmp_path / "export"
    assert main(["export", str(out), "-w", str(ws)]) == 0
    assert stat.S_IMODE(out.stat().st_mode) == 0o700
    files = sorted(out.iterdir())
    assert {f.name for f in files} >= {"trials.csv", "events.csv", "samples_linear.csv", "data_dictionary.json",
                                       "datapackage.json"}
    for f in files:
        assert stat.S_IMODE(f.stat().st_mode) == 0o600, f
    events = (out / "events.csv").read_text()
    assert HOST not in events and str(PID) not in events and "session_process" not in events
    rows = list(csv.reader(io.StringIO(events)))
    assert not {"host", "hostname", "pid"} & set(rows[0]), rows[0]
    payloads = [json.loads(cell) for row in rows[1:] for cell in row if cell.startswith("{")]
    assert payloads and not any({"host", "hostname", "pid"} & set(p) for p in payloads)  # nor inside a payload
    with_info = tmp_path / "with-info"
    assert main(["export", str(with_info), "-w", str(ws), "--process-info", "--no-samples"]) == 0
    assert HOST in (with_info / "events.csv").read_text()
    parquet = tmp_path / "parquet"
    assert main(["export", str(parquet), "-w", str(ws), "--format", "parquet"]) == 0
    written = sorted(parquet.iterdir())
    assert "events.parquet" in {f.name for f in written}
    assert all(stat.S_IMODE(f.stat().st_mode) == 0o600 for f in written)
    assert HOST.encode() not in (parquet / "events.parquet").read_bytes()
    assert main(["export", str(tmp_path / "x"), "-w", str(ws), "--format", "xlsx"]) != 0
    err = capsys.readouterr().err
    assert err.count("Error:") == 1 and "allowed: csv, parquet" in err and not (tmp_path / "x").exists()
