"""``studyctl bench NAME [--json]``: run one benchmark and print its figures."""

from __future__ import annotations

import json

import typer

from studyctl import bench as bench_lib
from studyctl.cli.common import output_console


def register(app: typer.Typer) -> None:
    @app.command("bench")
    def bench(
        name: str = typer.Argument(..., help="Benchmark to run (store, schedule, engine, capr, stats, …)."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object with the figures."),
        quick: bool = typer.Option(False, "--quick", help="Fewer repetitions: a smoke run, not a measurement."),
        workers: int | None = typer.Option(
            None, "--workers", help="Local Dask workers of benchmarks that start a cluster (power, power_curve); "
            "1 runs serially without a cluster, for a shared machine. Default: one per core."),
    ) -> None:
        """Measure one capability's speed (and speed against error) and print its figures."""
        result = bench_lib.load(name)(quick=quick, **bench_lib.worker_options(name, workers))
        if as_json:
            typer.echo(json.dumps(result.to_json(), default=float))
            return
        from studyctl.report.terminal import bench_tables  # noqa: PLC0415 - only when a table is printed

        console = output_console()
        for table in bench_tables(result):
            console.print(table)
        for note in result.notes:
            console.print(f"[dim]{note}[/dim]")
