"""A built wheel carries the migrations, and an installed (non-editable) studyctl finds them."""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from studyctl.store.db import head_revision

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_wheel_ships_migrations_and_init_finds_them(tmp_path):
    wheels = tmp_path / "wheels"
    # Build from a clean copy: an in-tree build/ folder could carry stale files into the wheel.
    source = tmp_path / "src"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(
        ".git", ".venv*", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache", ".ruff_cache", "reports",
        ".hypothesis", "demo"))
    # Reuse the environment's setuptools when it has one (fast, offline); else pip fetches it.
    isolation = ["--no-build-isolation"] if importlib.util.find_spec("setuptools") else []
    build = subprocess.run(  # -v: pip passes on what setuptools says about our packaging
        [sys.executable, "-m", "pip", "wheel", "-v", "--no-deps", *isolation, "-w", str(wheels), str(source)],
        capture_output=True, text=True, timeout=300,
    )
    assert build.returncode == 0, build.stderr[-2000:]
    # no warnings from our own packaging (a license table, a data folder missing from the packages …); the
    # byte-compiling notes come from PYTHONDONTWRITEBYTECODE in the environment, and the index notes from pip's config
    said = [line for line in (build.stdout + build.stderr).splitlines()
            if re.search(r"warn|deprecat", line, re.I) and "byte-compiling is disabled" not in line
            and "is ignored: it is neither a file nor a directory" not in line]
    assert said == [], said[:20]
    wheel = next(wheels.glob("studyctl-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for needed in ("env.py", "script.py.mako", "versions/0001_initial_schema.py"):
        assert f"studyctl/_resources/migrations/{needed}" in names
    # Data that is not a Python package must ship too: the participant view's page, the shipped plans' CSV.
    for needed in (
        "studyctl/view/static/index.html",
        "studyctl/view/static/view.js",
        "studyctl/view/static/view.css",
        "studyctl/models/fingertip_roi.csv",
        "studyctl/_resources/analysis/data/pseudo_haptic_palpation_published.csv",
        "studyctl/_resources/protocols/needle_insertion.yaml",
    ):
        assert needed in names, f"{needed} is missing from the wheel"
    target = tmp_path / "site"
    install = subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(wheel)],
        capture_output=True, text=True, timeout=300,
    )
    assert install.returncode == 0, install.stderr[-2000:]
    env = {**os.environ, "PYTHONPATH": str(target)}
    env.pop("STUDYCTL_DB", None)
    probe = subprocess.run(
        [sys.executable, "-c", "import studyctl, studyctl.resources as r; print(studyctl.__file__); "
         "print(r.resource_dir('migrations'))"],
        capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120,
    )
    assert probe.returncode == 0, probe.stderr
    module_file, migrations = probe.stdout.split()
    assert module_file.startswith(str(target)) and migrations.startswith(str(target))
    ws = tmp_path / "ws"
    init = subprocess.run([sys.executable, "-m", "studyctl", "init", str(ws)], capture_output=True, text=True,
                          env=env, cwd=tmp_path, timeout=120)
    assert init.returncode == 0, init.stderr
    current = subprocess.run([sys.executable, "-m", "studyctl", "db", "current", "-w", str(ws)],
                             capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert current.returncode == 0 and f"revision {head_revision()}" in current.stdout, current.stderr
