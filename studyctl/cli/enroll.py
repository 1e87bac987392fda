"""``studyctl enroll [--group G]``: enroll the next participant and print the code and sequence."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from studyctl.cli.common import DB_OPTION, STUDY_OPTION, WORKSPACE_OPTION, workspace_arg
from studyctl.protocol.stored_plan import format_placement
from studyctl.store.enrollment import Enrollment
from studyctl.store.enrollment import enroll as enroll_participant
from studyctl.store.workspace import open_study


def register(app: typer.Typer) -> None:
    @app.command("enroll")
    def enroll(
        group: str = typer.Option(None, "--group", "-g", help="Stratum to enroll into (e.g. novice, expert)."),
        code: str = typer.Option(None, "--code", help="Use this participant code instead of a random one."),
        over_target: bool = typer.Option(False, "--over-target", help="Enroll even though the group's (or study's) "
                                         "target size is reached."),
        as_json: bool = typer.Option(False, "--json", help="Print the enrollment and plan as one JSON object: "
                                     "slot_number and sequence_number count from 1 as the text does (sequence_number "
                                     "null: random order); slot_index and sequence_index, and the stored schedule's "
                                     "slot and sequence, count from 0."),
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
    ) -> None:
        """Enroll the next participant: a new pseudonymous code, the next sequence slot and a stored plan."""
        with open_study(db, workspace_arg(workspace), study) as opened:
            result = enroll_participant(opened.store, group, study=opened.study.name, code=code,
                                        over_target=over_target)
        if as_json:
            typer.echo(json.dumps({"code": result.code, "stratum": result.stratum, **slot_fields(result),
                                   "over_target": result.over_target, "schedule": result.schedule.to_json()}))
            return
        numbers = slot_fields(result)
        sequence = ("random order" if numbers["sequence_number"] is None
                    else f"sequence {numbers['sequence_number']}")
        typer.echo(f"Enrolled {result.code} in group {result.stratum}: slot {numbers['slot_number']}, {sequence}")
        typer.echo(f"  order: {' → '.join(result.order)}")
        if result.over_target:
            typer.echo(f"  over the target: {result.over_target}; enrolled on purpose (--over-target), recorded")
        for e in result.schedule.entries:
            extra = []
            if e.placement is not None:
                extra.append(f"placement {format_placement(e.placement)}")
            if e.orientation_deg is not None:
                extra.append(f"orientation {e.orientation_deg:g}°")
            if e.questionnaires_after:
                extra.append(f"then {', '.join(e.questionnaires_after)}")
            typer.echo(f"  trial {e.trial:>3}: {e.condition} (block {e.block}, repetition {e.repetition})"
                       + ("; " + "; ".join(extra) if extra else ""))


def slot_fields(result: Enrollment) -> dict[str, int | None]:
    """The slot and sequence, named by their base: a coordinator reads "slot 1, sequence 1" (the numbers, from 1, as
    the schedule export's slot column), the stored plan keeps indices from 0. The text and --json both come from
    here, so they cannot disagree again (--json gave the 0-based slot beside the text's 1-based one)."""
    seq = result.sequence
    return {"slot_number": result.slot + 1, "sequence_number": None if seq is None else seq + 1,
            "slot_index": result.slot, "sequence_index": seq}
