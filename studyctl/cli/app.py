"""Assemble the ``studyctl`` command from one module per command group.

Each module in :data:`COMMAND_MODULES` exposes ``register(app: typer.Typer) -> None``.
"""

from __future__ import annotations

import importlib
import os
import sys

import typer
import typer.core

from studyctl import __version__
from studyctl.errors import StudyctlError

COMMAND_MODULES = (
    "studyctl.cli.bench",
    "studyctl.cli.calibrate",
    "studyctl.cli.plugins",
    "studyctl.cli.protocol",
    "studyctl.cli.enroll",
    "studyctl.cli.records",
    "studyctl.cli.study",
    "studyctl.cli.session",
    "studyctl.cli.db",
    "studyctl.cli.audit",
    "studyctl.cli.analysis",
    "studyctl.cli.power",
    "studyctl.cli.device",
)

def _flags_without_type(core) -> None:  # noqa: ANN001 - typer.core
    """Help shows no ``<bool>`` placeholder after a flag (``--json``, ``--keep-data/--delete-data``): a flag takes
    no value. Typer (0.2x) prints every option's type in the help; the value options keep theirs (``<str>``)."""
    option = getattr(core, "TyperOption", None)
    shown = getattr(option, "display_type_rich", None)
    if shown is None or getattr(shown, "_studyctl", False):
        return

    def display_type_rich(self, ctx):  # noqa: ANN001, ANN202
        return None if getattr(self, "is_flag", False) else shown(self, ctx)

    display_type_rich._studyctl = True
    option.display_type_rich = display_type_rich


_flags_without_type(typer.core)

# Each top-level command (or command group) and the module that registers it: a command line names one, and only
# that module is imported (`studyctl run` never loads the statistics, `protocol check` never the engine; a hostile
# input is refused by a small process). Help, completion and unknown commands build the whole app. A test checks
# this table against what the modules register.
COMMANDS = {
    "bench": "studyctl.cli.bench", "calibrate": "studyctl.cli.calibrate", "plugins": "studyctl.cli.plugins",
    "protocol": "studyctl.cli.protocol", "enroll": "studyctl.cli.enroll", "withdraw": "studyctl.cli.records",
    "consent": "studyctl.cli.records", "note": "studyctl.cli.records", "init": "studyctl.cli.study",
    "status": "studyctl.cli.study", "run": "studyctl.cli.session", "resume": "studyctl.cli.session",
    "export": "studyctl.cli.session", "db": "studyctl.cli.db", "audit": "studyctl.cli.audit",
    "analyze": "studyctl.cli.analysis", "report": "studyctl.cli.analysis", "simulate": "studyctl.cli.analysis",
    "demo": "studyctl.cli.analysis", "power": "studyctl.cli.power", "device": "studyctl.cli.device",
}


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"studyctl {__version__}")
        raise typer.Exit()


def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version_callback, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Run human-subject studies of haptic feedback, from the protocol to the published statistics."""


def build_app(modules: tuple[str, ...] = COMMAND_MODULES) -> typer.Typer:
    """The ``studyctl`` command with the commands of ``modules`` (all of them by default)."""
    built = typer.Typer(
        name="studyctl",
        help="Run human-subject studies of haptic feedback, from the protocol to the published statistics.",
        no_args_is_help=True,
        add_completion=True,
        pretty_exceptions_enable=False,
    )
    built.callback()(_root)
    for module in modules:
        importlib.import_module(module).register(built)
    return built


_whole: typer.Typer | None = None


def __getattr__(name: str) -> typer.Typer:
    """``app``: the whole command, built on first use (tests and tools import it)."""
    global _whole
    if name != "app":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    if _whole is None:
        _whole = build_app()
    return _whole


def app_for(args: list[str]) -> typer.Typer:
    """The command for one command line: only the module of the command it names, when it names a known one."""
    completing = any(k.startswith("_") and k.endswith("_COMPLETE") for k in os.environ)
    if args and not completing and args[0] in COMMANDS:
        return build_app((COMMANDS[args[0]],))
    return sys.modules[__name__].app  # the whole command (or one a test put in its place)


def main(argv: list[str] | None = None) -> int:
    """Console entry point: run the CLI and turn any StudyctlError into one ``Error:`` line."""
    try:
        # In non-standalone mode click hands ``typer.Exit(n)`` back as the return value.
        args = sys.argv[1:] if argv is None else list(argv)
        returned = app_for(args)(args=args, standalone_mode=False)
    except StudyctlError as exc:
        typer.echo(f"Error: {exc}", err=True)
        return exc.exit_code
    except typer.Abort:
        typer.echo("Aborted.", err=True)
        return 130
    except KeyboardInterrupt:
        typer.echo("Interrupted.", err=True)
        return 130
    except typer.Exit as exc:
        return exc.exit_code
    except Exception as exc:
        # Usage errors of the underlying click layer (typer may vendor it) arrive here in
        # non-standalone mode; anything else is a bug and keeps its traceback.
        if hasattr(exc, "show") and hasattr(exc, "exit_code"):
            exc.show()
            return int(exc.exit_code)
        raise
    return returned if isinstance(returned, int) else 0


def console_main() -> None:
    sys.exit(main())
