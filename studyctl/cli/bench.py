"""``studyctl bench NAME [--json]``: run one benchmark and print its figures."""

from __future__ import annotations

import json

import typer
from rich.table import Table

from studyctl import bench as bench_lib
from studyctl.cli.common import output_console


def register(app: typer.Typer) -> None:
    @app.command("bench")
    def bench(
        name: str = typer.Argument(..., help="Benchmark to run (store, schedule, engine, capr, stats, …)."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object with the figures."),
        quick: bool = typer.Option(False, "--quick", help="Fewer repetitions: a smoke run, not a measurement."),
    ) -> None:
        """Measure one capability's speed (and speed against error) and print its figures."""
        result = bench_lib.load(name)(quick=quick)
        if as_json:
            typer.echo(json.dumps(result.to_json(), default=float))
            return
        console = output_console()
        table = Table(title=f"studyctl bench {result.name}")
        table.add_column("figure")
        table.add_column("value", justify="right")
        table.add_column("peer (same run)", justify="right")
        for key, value in result.figures.items():
            peer = result.peers.get(key)
            table.add_row(key, f"{value:.4g}", "" if peer is None else f"{peer:.4g}")
        for key, value in result.peers.items():
            if key not in result.figures:
                table.add_row(key, "", f"{value:.4g}")
        console.print(table)
        for title, rows in result.tables.items():
            if not rows:
                continue
            sub = Table(title=title)
            for col in rows[0]:
                sub.add_column(str(col))
            for row in rows:
                sub.add_row(*(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row.values()))
            console.print(sub)
        for note in result.notes:
            console.print(f"[dim]{note}[/dim]")
