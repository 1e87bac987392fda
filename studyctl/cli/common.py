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
