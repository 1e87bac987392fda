"""Paths and settings of the small palpation study the power tests simulate (see conftest.py)."""

from pathlib import Path

DATA = Path(__file__).parent / "data"
PROTOCOL = DATA / "mini_palpation.yaml"
PLAN = DATA / "mini_palpation_plan.yaml"
SIZES = (2, 4)
REPLICATES = 2
SEED = 20261122


def run_power_cli(args, capsys):
    """``studyctl power ARGS`` in-process: (exit code, stdout, stderr). Shared here because a bare
    ``from test_cli import …`` resolves to whichever test_cli module (tests/view has one) was imported first."""
    from studyctl.cli.app import main

    code = main(["power", *map(str, args)])
    out = capsys.readouterr()
    return code, out.out, out.err
