"""``studyctl db upgrade|current|check``: the database schema and its integrity."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from studyctl.cli.common import DB_OPTION, WORKSPACE_OPTION, workspace_arg
from studyctl.store.db import Database, require_head
from studyctl.store.maintenance import check_database, upgrade_database
from studyctl.store.workspace import resolve_database

JSON_OPTION = typer.Option(False, "--json", help="Print one JSON object instead of text.")


def register(app: typer.Typer) -> None:
    db_app = typer.Typer(help="Inspect, upgrade and check the study database.", no_args_is_help=True)

    @db_app.command("upgrade")
    def upgrade(db: str = DB_OPTION, workspace: Path = WORKSPACE_OPTION, as_json: bool = JSON_OPTION) -> None:
        """Migrate the database to this studyctl's newest schema revision (back it up first)."""
        url, _ = resolve_database(db, workspace_arg(workspace))
        before, after = upgrade_database(url)
        if as_json:
            typer.echo(json.dumps({"from": before, "to": after.current, "changed": before != after.current}))
        elif before == after.current:
            typer.echo(f"Already at the newest schema revision {after.current}.")
        else:
            typer.echo(f"Upgraded the schema from {before or 'empty'} to {after.current}.")

    @db_app.command("current")
    def current(db: str = DB_OPTION, workspace: Path = WORKSPACE_OPTION, as_json: bool = JSON_OPTION) -> None:
        """Print the database's schema revision; exit non-zero unless it is this studyctl's newest."""
        url, _ = resolve_database(db, workspace_arg(workspace))
        with Database.open(url, check_schema=False) as database:
            state = database.schema_state()
            if as_json:
                typer.echo(json.dumps({"database": database.describe(), "revision": state.current,
                                       "head": state.head}))
            else:
                typer.echo(f"{database.describe()}: revision {state.current or 'none'} (studyctl head {state.head})")
            require_head(state, database.describe())

    @db_app.command("check")
    def check(db: str = DB_OPTION, workspace: Path = WORKSPACE_OPTION, as_json: bool = JSON_OPTION) -> None:
        """Check the database file's integrity, the audit hash chain and the stored sample chunks."""
        url, _ = resolve_database(db, workspace_arg(workspace))
        report = check_database(url)
        if as_json:  # printed before the exit status says whether it passed
            typer.echo(json.dumps({"database": report.database, "ok": report.ok,
                                   "checks": [{"check": n, "passed": ok, "detail": d} for n, ok, d in report.checks]}))
        else:
            for line in report.lines():
                typer.echo(line)
        report.raise_for_problems()

    app.add_typer(db_app, name="db")
