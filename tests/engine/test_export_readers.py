"""The export loads outside studyctl: DuckDB reads the Parquet and the CSV files, R reads the CSV export typed
from datapackage.json (``tests/reference/export/read_export.R``); every table has the rows, columns and numbers
that :func:`read_export` gives."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from studyctl.engine.export import export_study, read_export
from studyctl.store.workspace import open_study

R_SCRIPT = Path(__file__).parents[1] / "reference" / "export" / "read_export.R"


@pytest.fixture
def exports(tmp_path, scripted_person_study):
    with open_study(workspace=scripted_person_study) as o:
        export_study(o.store, tmp_path / "csv")
        export_study(o.store, tmp_path / "pq", format="parquet")
    return tmp_path / "csv", tmp_path / "pq"


def _numbers(frame: pd.DataFrame) -> dict[str, float]:
    return {c: float(pd.to_numeric(frame[c]).sum()) for c in frame.columns
            if str(frame[c].dtype) in ("Int64", "float64")}


def test_duckdb_reads_both_formats(exports):
    duckdb = pytest.importorskip("duckdb")  # in the test extra
    csv_dir, pq_dir = exports
    tables = read_export(pq_dir)
    con = duckdb.connect()
    for name, frame in tables.items():
        for path, reader in ((pq_dir / f"{name}.parquet", "read_parquet"), (csv_dir / f"{name}.csv", "read_csv")):
            if frame.empty and reader == "read_csv":
                continue  # a header-only CSV has no rows to infer types from
            got = con.execute(f"SELECT * FROM {reader}(?)", [str(path)]).df()
            assert list(got.columns) == list(frame.columns) and len(got) == len(frame), (name, reader)
            for col, total in _numbers(frame).items():
                assert np.isclose(float(pd.to_numeric(got[col]).sum()), total, rtol=1e-12), (name, reader, col)
    samples = con.execute(f"SELECT count(*), count(DISTINCT trial_id) FROM read_parquet('{pq_dir}/samples_*.parquet',"
                          " union_by_name = true)").fetchone()
    assert samples[0] == sum(len(f) for n, f in tables.items() if n.startswith("samples_")) and samples[1] == 2


@pytest.mark.slow  # starts Rscript
@pytest.mark.skipif(shutil.which("Rscript") is None, reason="R is not installed (apt-get install r-base-core "
                    "r-cran-jsonlite)")
def test_r_reads_the_csv_export_typed(exports):
    csv_dir, _ = exports
    run = subprocess.run(["Rscript", str(R_SCRIPT), str(csv_dir)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout)
    assert got["R"].startswith("R version")
    for name, frame in read_export(csv_dir).items():
        assert got[name]["rows"] == len(frame) and got[name]["columns"] == list(frame.columns), name
        sums = got[name]["sums"] or {}
        for col, total in _numbers(frame).items():
            assert np.isclose(sums[col], total, rtol=1e-12), (name, col)
