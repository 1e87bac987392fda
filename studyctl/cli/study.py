"""``studyctl init DIR`` and ``studyctl status``."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from studyctl.cli.common import DB_OPTION, STUDY_OPTION, WORKSPACE_OPTION, workspace_arg
from studyctl.engine.progress import progress_json, progress_lines, study_progress
from studyctl.store.status import study_status
from studyctl.store.workspace import init_workspace, open_study


def register(app: typer.Typer) -> None:
    @app.command("init")
    def init(
        folder: Path = typer.Argument(..., help="Workspace folder to create (may exist if it holds no study)."),
        protocol: str = typer.Option(
            None, "--protocol", help="Shipped protocol name or protocol file; validated and snapshotted."
        ),
        name: str = typer.Option(None, "--name", help="Study name (default: the protocol's study id or folder name)."),
        seed: int = typer.Option(None, "--seed", help="Master seed (default: the protocol's, else random)."),
        db: str = typer.Option(
            None, "--db", help="PostgreSQL URL to hold the study instead of a new study.db in the folder."
        ),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object instead of text."),
    ) -> None:
        """Create a study workspace: studyctl.toml plus its database at the newest schema."""
        result = init_workspace(folder, protocol=protocol, name=name, db=db, seed=seed)
        if as_json:
            typer.echo(json.dumps({"study": result.study, "root": str(result.root), "database": str(result.database),
                                   "protocol": result.protocol_name, "protocol_sha256": result.protocol_sha256,
                                   "seed": result.seed}))
            return
        typer.echo(f"Created study {result.study!r} in {result.root}")
        typer.echo(f"  database: {result.database}")
        if result.protocol_name:
            typer.echo(f"  protocol: {result.protocol_name} (sha256 {result.protocol_sha256})")
        typer.echo(f"  seed:     {result.seed}")

    @app.command("status")
    def status(
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object instead of text."),
    ) -> None:
        """Show the study, its protocol and how many participants, sessions and trials are in each state."""
        with open_study(db, workspace_arg(workspace), study) as opened:
            info = study_status(opened.store, opened.study)
            progress = study_progress(opened.store, opened.study.name)  # the session engine's per-condition view
        if as_json:
            typer.echo(json.dumps({
                "study": info.study, "protocol": info.protocol_name, "protocol_sha256": info.protocol_sha256,
                "seed": info.seed, "database": info.database, "participants": info.participants,
                "sessions": info.sessions, "trials": info.trials, "rehearsal_sessions": info.rehearsal_sessions,
                "rehearsal_trials": info.rehearsal_trials, "progress": progress_json(progress),
            }))
            return
        # Plain echo, not rich markup: names are shown verbatim whatever characters they hold.
        typer.echo(f"study:    {info.study}")
        typer.echo(f"database: {info.database}")
        proto = f"{info.protocol_name} (sha256 {info.protocol_sha256})" if info.protocol_name else "none"
        typer.echo(f"protocol: {proto}")
        typer.echo(f"seed:     {info.seed}")
        for title, counts in (("participants", info.participants), ("sessions", info.sessions),
                              ("trials", info.trials)):
            parts = ", ".join(f"{k} {v}" for k, v in counts.items())
            typer.echo(f"{title + ':':<13} {sum(counts.values())} ({parts})")
        if any(info.rehearsal_sessions.values()):  # recorded, but neither data nor progress: apart from the totals
            n_trials = sum(info.rehearsal_trials.values())
            typer.echo(f"{'rehearsals:':<13} {sum(info.rehearsal_sessions.values())} sessions, {n_trials} trials "
                       "(run --rehearse; not counted above, never analysed)")
        for line in progress_lines(progress):
            typer.echo(line)
