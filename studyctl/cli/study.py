"""``studyctl init DIR`` and ``studyctl status``."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from studyctl.cli.common import DB_OPTION, STUDY_OPTION, WORKSPACE_OPTION, complete_shipped, workspace_arg
from studyctl.errors import UsageError


def register(app: typer.Typer) -> None:
    @app.command("init")
    def init(
        folder: Path = typer.Argument(..., help="Workspace folder to create (may exist if it holds no study)."),
        protocol: str = typer.Option(
            None, "--protocol", help="Shipped protocol name or protocol file; validated and snapshotted.",
            autocompletion=complete_shipped("protocols"),
        ),
        name: str = typer.Option(None, "--name", help="Study name (default: the protocol's study id or folder name)."),
        seed: int = typer.Option(None, "--seed", help="Master seed (default: the protocol's, else random)."),
        db: str = typer.Option(
            None, "--db", help="PostgreSQL URL to hold the study instead of a new study.db in the folder."
        ),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object instead of text."),
    ) -> None:
        """Create a study workspace: studyctl.toml plus its database at the newest schema."""
        loaded = None
        if protocol is not None:  # read before the store is imported: a hostile protocol is refused by a small
            from studyctl.protocol import load_protocol, resolve_protocol  # process (issue 19); read once

            loaded = load_protocol(resolve_protocol(protocol))
        from studyctl.store.workspace import init_workspace

        result = init_workspace(folder, protocol=loaded, name=name, db=db, seed=seed)
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
        watch: bool = typer.Option(False, "--watch", help="Keep the view on screen, re-read every --interval "
                                   "seconds (read-only; Ctrl-C stops it)."),
        interval: float = typer.Option(2.0, "--interval", min=0.2, max=3600.0,
                                       help="Seconds between refreshes of --watch."),
    ) -> None:
        """Show the study, its protocol and how many participants, sessions and trials are in each state."""
        if watch and as_json:
            raise UsageError("--watch shows a live view for a person; for scripts poll `studyctl status --json`")
        from studyctl.engine.data_gaps import data_gaps, gaps_json
        from studyctl.engine.progress import progress_json, study_progress
        from studyctl.store.status import study_status
        from studyctl.store.workspace import open_study

        def read() -> tuple:  # noqa: ANN202
            with open_study(db, workspace_arg(workspace), study) as opened:
                return (study_status(opened.store, opened.study),
                        study_progress(opened.store, opened.study.name),  # the engine's per-condition view
                        data_gaps(opened.store, opened.study.name))

        info, progress, gaps = read()
        if as_json:
            typer.echo(json.dumps({
                "study": info.study, "protocol": info.protocol_name, "protocol_sha256": info.protocol_sha256,
                "seed": info.seed, "database": info.database, "participants": info.participants,
                "sessions": info.sessions, "trials": info.trials, "rehearsal_sessions": info.rehearsal_sessions,
                "rehearsal_trials": info.rehearsal_trials, "progress": progress_json(progress),
                "data": gaps_json(gaps),
            }))
            return
        if not watch:
            for line in _status_lines(info, progress, gaps):
                typer.echo(line)
            return
        import time
        from datetime import datetime

        from rich.console import Console
        from rich.live import Live
        from rich.text import Text

        def view(info, progress, gaps) -> Text:  # noqa: ANN001
            # Text, not markup: names are shown verbatim whatever characters they hold
            stamp = datetime.now().strftime("%H:%M:%S")
            # the stamp first: a view taller than the terminal is cut at the bottom
            return Text("\n".join([f"(read at {stamp}; every {interval:g} s; Ctrl-C to stop)",
                                   *_status_lines(info, progress, gaps)]))

        with Live(view(info, progress, gaps), console=Console(highlight=False), auto_refresh=False) as live:
            try:
                while True:
                    time.sleep(interval)
                    live.update(view(*read()), refresh=True)
            except KeyboardInterrupt:
                pass


def _status_lines(info, progress, gaps) -> list[str]:  # noqa: ANN001
    """The text of ``studyctl status`` (also the body of ``--watch``)."""
    from studyctl.engine.data_gaps import gap_lines
    from studyctl.engine.progress import progress_lines

    lines = [f"study:    {info.study}", f"database: {info.database}"]
    proto = f"{info.protocol_name} (sha256 {info.protocol_sha256})" if info.protocol_name else "none"
    lines += [f"protocol: {proto}", f"seed:     {info.seed}"]
    for title, counts in (("participants", info.participants), ("sessions", info.sessions),
                          ("trials", info.trials)):
        parts = ", ".join(f"{k} {v}" for k, v in counts.items())
        lines.append(f"{title + ':':<13} {sum(counts.values())} ({parts})")
    if any(info.rehearsal_sessions.values()):  # recorded, but neither data nor progress: apart from the totals
        lines.append(f"{'rehearsals:':<13} {sum(info.rehearsal_sessions.values())} sessions, "
                     f"{sum(info.rehearsal_trials.values())} trials "
                     "(run --rehearse; not counted above, never analysed)")
    data = gap_lines(gaps)  # the totals near the top (a --watch taller than the terminal is cut at the bottom)
    return lines + data[:1] + list(progress_lines(progress)) + data[1:]
