"""Options every command that touches a study database shares (``--db``, ``--workspace``, ``--study``).

Use them as defaults of typer parameters and open the study with
:func:`studyctl.store.workspace.open_study` (``--db`` first, then ``STUDYCTL_DB``, then the workspace).
"""

from __future__ import annotations

from pathlib import Path

import typer

DB_OPTION = typer.Option(
    None,
    "--db",
    envvar="STUDYCTL_DB",
    show_envvar=True,
    help="Database URL (postgresql://USER@HOST:PORT/DB or sqlite:///PATH); default: the workspace's database.",
)
WORKSPACE_OPTION = typer.Option(
    None, "--workspace", "-w", help="Workspace folder (holds studyctl.toml); default: the current folder."
)
STUDY_OPTION = typer.Option(None, "--study", help="Study name, when the database holds several studies.")


def workspace_arg(value: Path | None) -> str | None:
    return None if value is None else str(value)


# Width of rich output that goes to a file or pipe: wide enough that no table cell or title is cropped
# (rich assumes 80 columns when it cannot ask a terminal, and cuts what does not fit).
PIPED_WIDTH = 400


def output_console(*, stderr: bool = False):  # noqa: ANN201 - rich.console.Console (imported lazily)
    """A rich console for results: the terminal's width, or :data:`PIPED_WIDTH` when the stream is not a terminal
    (and COLUMNS does not say otherwise), so a piped or redirected table is whole."""
    import os
    import sys

    from rich.console import Console

    stream = sys.stderr if stderr else sys.stdout
    piped = not (hasattr(stream, "isatty") and stream.isatty()) and "COLUMNS" not in os.environ
    return Console(stderr=stderr, highlight=False, width=PIPED_WIDTH if piped else None)


def complete_shipped(kind: str):  # noqa: ANN201 - a typer autocompletion callback
    """Shell completion of a shipped protocol (``kind`` protocols) or analysis plan (analysis) name; an empty
    answer lets the shell complete file names instead."""

    def complete(incomplete: str) -> list[str]:
        from studyctl.resources import shipped_names

        return [n for n in shipped_names(kind) if n.startswith(incomplete)]

    return complete
