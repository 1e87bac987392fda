"""``studyctl withdraw|consent|note``: the coordinator's records around the trials (all audited)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from studyctl.cli.common import DB_OPTION, STUDY_OPTION, WORKSPACE_OPTION, workspace_arg
from studyctl.store.coordination import add_note, record_consent, withdraw
from studyctl.store.workspace import open_study

JSON_OPTION = typer.Option(False, "--json", help="Print the result as one JSON object.")


def register(app: typer.Typer) -> None:
    @app.command("withdraw")
    def withdraw_cmd(
        code: str = typer.Argument(..., help="Participant code."),
        reason: str = typer.Option(..., "--reason", help="Why the participant withdrew (stored, audited)."),
        keep_data: bool = typer.Option(True, "--keep-data/--delete-data",
                                       help="Keep what was recorded (default), or erase it: trials, events, samples, "
                                       "answers, reports and sessions are deleted, one audit row lists their "
                                       "digests (audit verify reports the erasure). Also for a participant who "
                                       "withdrew earlier with their data kept."),
        as_json: bool = JSON_OPTION,
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
    ) -> None:
        """Withdraw a participant: no further sessions, open sessions closed, remaining trials dropped (and with
        --delete-data their recorded data erased, audited)."""
        with open_study(db, workspace_arg(workspace), study) as opened:
            r = withdraw(opened.store, code, reason=reason, keep_data=keep_data, study=opened.study.name)
        if as_json:
            typer.echo(json.dumps(r.to_frame().iloc[0].to_dict() | {"sessions_closed": list(r.sessions_closed),
                                                                     "erased": r.erased}, default=int))
            return
        if r.erased is not None:
            what = ", ".join(f"{n} {k}{'' if n == 1 else 's'}" for k, n in r.erased.items() if n)
            typer.echo(f"Erased the recorded data of {r.code}: {what or 'nothing recorded'} (listed by digest in the "
                       "audit log; `studyctl audit verify` reports the erasure)")
        if r.trials_done or r.trials_dropped or r.keep_data or r.sessions_closed:
            done = "kept" if r.keep_data else "erased"
            typer.echo(f"Withdrew {r.code}: {r.trials_done} trials done {done}, {r.trials_dropped} planned trials "
                       "dropped" + (f", session(s) {', '.join(map(str, r.sessions_closed))} closed"
                                    if r.sessions_closed else ""))
        typer.echo("  their slot goes to the next enrollee" if r.slot_freed else
                   "  their slot stays taken (the protocol does not replace withdrawn participants)")

    @app.command("consent")
    def consent_cmd(
        code: str = typer.Argument(..., help="Participant code."),
        version: str = typer.Option(..., "--version", help="Version of the consent form the participant signed."),
        as_json: bool = JSON_OPTION,
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
    ) -> None:
        """Record a participant's consent (the protocol's study.consent_version, when it declares one)."""
        with open_study(db, workspace_arg(workspace), study) as opened:
            r = record_consent(opened.store, code, version=version, study=opened.study.name)
        typer.echo(json.dumps(r) if as_json else f"Recorded consent of {r['code']} on version {r['version']}")

    @app.command("note")
    def note_cmd(
        text: str = typer.Argument(..., help="The note."),
        session: int = typer.Option(None, "--session", help="Session the note is about."),
        trial: int = typer.Option(None, "--trial", help="Trial (attempt id) the note is about."),
        as_json: bool = JSON_OPTION,
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
    ) -> None:
        """Add a free-text note on a session, a trial or the study (audited; in the export)."""
        with open_study(db, workspace_arg(workspace), study) as opened:
            r = add_note(opened.store, text, session=session, trial=trial, study=opened.study.name)
        where = f"trial {trial}" if trial is not None else f"session {session}" if session is not None else "the study"
        typer.echo(json.dumps(r) if as_json else f"Noted on {where}")
