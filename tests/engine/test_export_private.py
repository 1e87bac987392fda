"""Exports are private like the database (0600 files, 0700 folder) and carry no host or pid unless asked."""

from __future__ import annotations

import socket
import stat

from studyctl.cli.app import main
from studyctl.store.workspace import open_study


def test_export_files_are_private_and_anonymous(tmp_path, capsys, scripted_person_study):
    ws = scripted_person_study
    with open_study(workspace=ws) as o:
        # what older studyctl versions stored with every session start and resume
        o.store.append_event(1, "session_process", {"pid": 4242, "host": socket.gethostname()}, t_mono=0.0)
    out = tmp_path / "export"
    assert main(["export", str(out), "-w", str(ws)]) == 0
    assert stat.S_IMODE(out.stat().st_mode) == 0o700
    files = sorted(out.iterdir())
    assert {f.name for f in files} >= {"trials.csv", "events.csv", "samples_linear.csv", "data_dictionary.json",
                                       "datapackage.json"}
    for f in files:
        assert stat.S_IMODE(f.stat().st_mode) == 0o600, f
    events = (out / "events.csv").read_text()
    assert socket.gethostname() not in events and "4242" not in events and "session_process" not in events
    with_info = tmp_path / "with-info"
    assert main(["export", str(with_info), "-w", str(ws), "--process-info", "--no-samples"]) == 0
    assert socket.gethostname() in (with_info / "events.csv").read_text()
    parquet = tmp_path / "parquet"
    assert main(["export", str(parquet), "-w", str(ws), "--format", "parquet"]) == 0
    written = sorted(parquet.iterdir())
    assert "events.parquet" in {f.name for f in written}
    assert all(stat.S_IMODE(f.stat().st_mode) == 0o600 for f in written)
    assert socket.gethostname().encode() not in (parquet / "events.parquet").read_bytes()
    assert main(["export", str(tmp_path / "x"), "-w", str(ws), "--format", "xlsx"]) != 0
    err = capsys.readouterr().err
    assert err.count("Error:") == 1 and "allowed: csv, parquet" in err and not (tmp_path / "x").exists()
