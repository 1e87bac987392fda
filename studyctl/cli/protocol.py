"""``studyctl protocol check|show|schedule``: validate, summarise and preview a protocol."""

from __future__ import annotations

import json
from enum import StrEnum
from pathlib import Path

import typer

from studyctl.cli.common import complete_shipped
from studyctl.errors import UsageError
from studyctl.protocol import (
    expand_many,
    load_protocol,
    resolve_protocol,
    schedule_balance,
    schedule_rows,
)
from studyctl.protocol.summary import describe_protocol


class Format(StrEnum):
    table = "table"
    csv = "csv"
    json = "json"


def _load(file: str):
    return load_protocol(resolve_protocol(file))


def register(app: typer.Typer) -> None:
    group = typer.Typer(help="Check, summarise and preview study protocols.", no_args_is_help=True)
    app.add_typer(group, name="protocol")

    @group.command("check")
    def check(
        file: str = typer.Argument(..., help="Protocol YAML file, or the name of a shipped protocol.",
                                autocompletion=complete_shipped("protocols")),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object instead of text."),
    ) -> None:
        """Validate a protocol: exit 0 if valid, else list every problem (file:line:column, key path)."""
        protocol = _load(file)
        # a shipped protocol by its name, not the site-packages path it was installed to
        shown = protocol.path if Path(file).exists() else f"{file} (shipped)"
        if as_json:
            typer.echo(json.dumps({"ok": True, "protocol": shown, "study": protocol.study.id,
                                   "conditions": list(protocol.condition_ids), "strata": list(protocol.stratum_ids),
                                   "scheme": protocol.counterbalance.scheme, "sha256": protocol.sha256}))
            return
        typer.echo(f"OK: {shown} is a valid protocol ({protocol.study.id}: {len(protocol.conditions)} "
                   f"conditions, {len(protocol.participants.strata)} strata, scheme {protocol.counterbalance.scheme};"
                   f" sha256 {protocol.sha256[:12]})")

    @group.command("show")
    def show(
        file: str = typer.Argument(..., help="Protocol YAML file, or the name of a shipped protocol.",
                                autocompletion=complete_shipped("protocols")),
        as_json: bool = typer.Option(False, "--json", help="Print the validated protocol (every field, defaults "
                                     "filled in) and its counterbalancing sequences as one JSON object."),
    ) -> None:
        """Print a readable summary of a protocol: conditions, order, trial template, scene, questionnaires."""
        protocol = _load(file)
        if as_json:
            from studyctl.protocol.schedule import Planner

            sequences = Planner(protocol).sequences
            typer.echo(json.dumps({"study": protocol.study.id, "sha256": protocol.sha256,
                                   "sequences": None if sequences is None else [list(s) for s in sequences],
                                   "protocol": protocol.model_dump(mode="json")}))
            return
        typer.echo(describe_protocol(protocol))

    @group.command("schedule")
    def schedule(
        file: str = typer.Argument(..., help="Protocol YAML file, or the name of a shipped protocol.",
                                autocompletion=complete_shipped("protocols")),
        participants: int = typer.Option(..., "--participants", "-n", min=1, max=1_000_000,
                                         help="How many participants to plan (spread over strata by target_n)."),
        seed: int | None = typer.Option(None, "--seed", "-s", min=0,
                                        help="Schedule seed (default: the protocol's study.seed)."),
        fmt: Format = typer.Option(Format.table, "--format", "-f", help="table, csv or json."),
        as_json: bool = typer.Option(False, "--json", help="The same as --format json."),
    ) -> None:
        """Preview the schedules of N participants, with position and carry-over balance diagnostics."""
        if as_json:
            fmt = Format.json
        protocol = _load(file)
        if seed is None:
            seed = protocol.study.seed
        if seed is None:
            raise UsageError("no seed: pass --seed S or set study.seed in the protocol")
        schedules = expand_many(protocol, seed=seed, participants=participants)
        rows = schedule_rows(schedules)
        balance = schedule_balance(protocol, schedules)
        if fmt is Format.csv:
            typer.echo(rows.to_csv(index=False), nl=False)
            typer.echo(balance.summary_frame().to_string(index=False), err=True)
            return
        if fmt is Format.json:
            typer.echo(json.dumps({
                "protocol": protocol.study.id,
                "protocol_sha256": protocol.sha256,
                "seed": seed,
                "algorithm_version": schedules[0].algorithm_version if schedules else None,
                "rows": json.loads(rows.to_json(orient="records")),
                "balance": {
                    "summary": json.loads(balance.summary_frame().to_json(orient="records")),
                    "counts": json.loads(balance.to_frame().to_json(orient="records")),
                },
            }))
            return
        from studyctl.report.terminal import schedule_text  # noqa: PLC0415 - only this command draws the table

        typer.echo(schedule_text(protocol.study.id, participants, seed, schedules[0].algorithm_version, rows, balance))
