"""The CLI's contract: version, help on every command, errors as one line."""

from __future__ import annotations

import subprocess
import sys

import pytest
import typer.main

from studyctl import __version__
from studyctl.cli.app import app, main


def _walk(command, path: tuple[str, ...] = ()):
    yield path, command
    if hasattr(command, "commands"):
        for name, sub in command.commands.items():
            yield from _walk(sub, (*path, name))


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"studyctl {__version__}"


@pytest.mark.parametrize("path", [p for p, _ in _walk(typer.main.get_command(app))], ids=" ".join)
def test_every_command_has_help(path):
    root = typer.main.get_command(app)
    command = dict(_walk(root))[path]
    assert (command.help or "").strip(), f"studyctl {' '.join(path)} has no help text"


def test_unknown_benchmark_is_one_line_error(capsys):
    code = main(["bench", "no-such-benchmark"])
    err = capsys.readouterr().err
    assert code != 0
    assert err.startswith("Error: unknown benchmark 'no-such-benchmark'")
    assert "Traceback" not in err


@pytest.mark.slow
def test_console_script_runs():
    out = subprocess.run([sys.executable, "-m", "studyctl", "--help"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "Usage" in out.stdout


def test_exit_code_of_a_command_is_kept():
    import typer as _typer

    from studyctl.cli import app as app_module

    probe = _typer.Typer()

    @probe.command()
    def fail() -> None:
        """Exit with code 3."""
        raise _typer.Exit(3)

    original = app_module.app
    app_module.app = probe
    try:
        assert app_module.main([]) == 3
    finally:
        app_module.app = original


def test_the_command_table_names_the_module_that_registers_each_command():
    """A command line imports only its command's module (cli/app.COMMANDS): the table must say where each lives."""
    import importlib

    from studyctl.cli.app import COMMAND_MODULES, COMMANDS

    registered = {}
    for module in COMMAND_MODULES:
        one = typer.Typer()
        importlib.import_module(module).register(one)
        names = [c.name or c.callback.__name__.replace("_", "-") for c in one.registered_commands]
        names += [g.name or g.typer_instance.info.name for g in one.registered_groups]
        registered.update(dict.fromkeys(names, module))
    assert registered == COMMANDS
    assert set(COMMANDS) == set(typer.main.get_command(app).commands)


def test_a_command_line_imports_only_its_own_command_module():
    code = ("import sys\nfrom studyctl.cli.app import app_for\napp_for(['run', '--help'])\n"
            "print(sorted(m for m in sys.modules if m.startswith('studyctl.cli.')), 'pandas' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["['studyctl.cli.app',", "'studyctl.cli.common',", "'studyctl.cli.session']",
                                  "False"]


@pytest.mark.slow
def test_checking_and_store_commands_do_not_import_pandas(tmp_path):
    """pandas (+pyarrow) is ~90 MB of a process: `protocol check`, `status`, `audit verify` and `db check` (what
    refuses a hostile file or checks a study) build no table, so they stay small (issue 19's 200 MB bound)."""
    code = ("import sys\nfrom studyctl.cli.app import main\nfrom studyctl.store.workspace import init_workspace\n"
            f"init_workspace({str(tmp_path / 'ws')!r}, protocol='needle_insertion')\n"
            "codes = [main(['protocol', 'check', 'needle_insertion'])]\n"
            f"codes += [main([*c, '--workspace', {str(tmp_path / 'ws')!r}]) for c in "
            "(['status'], ['audit', 'verify'], ['db', 'check'])]\n"
            "print(codes, 'pandas' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[-1] == "[0, 0, 0, 0] False", out.stdout
