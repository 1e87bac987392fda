"""``studyctl plugins list``: the controllers, devices, scenes and participants this installation has."""

from __future__ import annotations

import json

import typer

from studyctl.cli.common import output_console
from studyctl.errors import PluginError
from studyctl.plugins.registry import list_plugins


def register(app: typer.Typer) -> None:
    plugins_app = typer.Typer(help="Inspect the installed plugins (built-in and third-party).", no_args_is_help=True)

    @plugins_app.command("list")
    def list_command(
        kind: str = typer.Option(None, "--kind", help="Only this kind: controller, device, scene or participant."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON array instead of a table."),
        strict: bool = typer.Option(False, "--strict", help="Exit non-zero when any plugin fails to import."),
    ) -> None:
        """List every registered plugin with its package, and say which ones fail to import and why."""
        listing = list_plugins(kind)
        frame = listing.to_frame()
        if as_json:
            typer.echo(json.dumps(frame.to_dict(orient="records")))
        else:
            console = output_console()
            # A narrow terminal cannot fit the description beside five columns: the failures' reasons
            # then follow the table, where they stay readable.
            wide = console.width >= 120
            from studyctl.report.terminal import plugins_table  # noqa: PLC0415 - only when a table is printed

            console.print(plugins_table(frame, wide=wide))
            if not wide:
                for row in frame.itertuples(index=False):
                    if row.status != "ok":
                        console.print(f"[red]{row.kind} {row.name}[/red]: {row.detail}", markup=True)
        if strict and listing.broken:
            names = ", ".join(f"{p.kind} {p.name}" for p in listing.broken)
            raise PluginError(f"{len(listing.broken)} plugin(s) failed to load: {names}")

    app.add_typer(plugins_app, name="plugins")
