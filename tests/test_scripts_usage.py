"""The developers' diagnostic scripts print what they do on ``--help`` instead of reading it as an argument."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPTS = sorted(p for p in (Path(__file__).parents[1] / "scripts").glob("*.py") if p.name != "script_usage.py")


@pytest.mark.slow  # one interpreter per script, each importing studyctl
@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_help_prints_the_scripts_usage_and_runs_nothing(script):
    done = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    first = done.stdout.strip().splitlines()[0]
    assert first.startswith("usage:") or len(first) > 20  # argparse's usage, or the docstring's first line
