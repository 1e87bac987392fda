"""export --format csv|parquet: payload fields as columns, samples per condition, a Frictionless data package,
and the two formats read back equal (Parquet much smaller where samples dominate)."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from studyctl.engine.export import export_study, read_export
from studyctl.store.workspace import open_study


def _size(folder: Path) -> int:
    return sum(f.stat().st_size for f in folder.iterdir())


def _check_same(csv_dir: Path, pq_dir: Path) -> dict[str, pd.DataFrame]:
    a, b = read_export(csv_dir), read_export(pq_dir)
    assert set(a) == set(b) and a
    for name in a:
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True, obj=name)
    return a


def _check_package(folder: Path, tables: dict[str, pd.DataFrame]) -> None:
    package = json.loads((folder / "datapackage.json").read_text())
    assert package["resources"]
    for res in package["resources"]:
        fields = res["schema"]["fields"]
        assert [f["name"] for f in fields] == list(tables[res["name"]].columns), res["name"]
        assert all(f["description"] and f["type"] in ("string", "integer", "number", "boolean", "datetime")
                   for f in fields)
        assert (folder / res["path"]).is_file()


def test_csv_and_parquet_read_back_equal_with_payload_columns(tmp_path, scripted_person_study):
    with open_study(workspace=scripted_person_study) as o:
        export_study(o.store, tmp_path / "csv")
        export_study(o.store, tmp_path / "pq", format="parquet")
    tables = _check_same(tmp_path / "csv", tmp_path / "pq")
    events = tables["events"]
    assert "payload" not in events.columns
    # a step's position is an integer column, a familiarisation's early end a boolean one
    assert str(events["payload_position"].dtype) == "Int64"
    assert events.loc[events.kind == "answer"].shape[0] == 3
    assert {"samples_none", "samples_linear"} <= set(tables)
    for fmt in ("csv", "pq"):
        _check_package(tmp_path / fmt, tables)
    units = {f["name"]: f.get("unit") for r in json.loads((tmp_path / "pq" / "datapackage.json").read_text())
             ["resources"] if r["name"] == "samples_linear" for f in r["schema"]["fields"]}
    assert units["t"] == "s" and any(u == "N" for k, u in units.items() if k.endswith("_n"))


@pytest.mark.slow
def test_parquet_export_of_a_simulated_study_is_a_fifth_of_the_csv(tmp_path):
    from studyctl.workflows.simulate import simulate_study

    simulate_study("needle_insertion", 1, 1, tmp_path / "ws")
    with open_study(workspace=tmp_path / "ws") as o:
        export_study(o.store, tmp_path / "csv")
        export_study(o.store, tmp_path / "pq", format="parquet")
    ratio = _size(tmp_path / "pq") / _size(tmp_path / "csv")
    assert ratio <= 0.2, ratio
    tables = _check_same(tmp_path / "csv", tmp_path / "pq")
    assert sum(len(f) for n, f in tables.items() if n.startswith("samples_")) > 10_000
