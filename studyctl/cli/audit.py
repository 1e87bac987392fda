"""``studyctl audit verify|show``: the hash-chained audit log."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from studyctl.cli.common import DB_OPTION, WORKSPACE_OPTION, workspace_arg
from studyctl.errors import IntegrityError
from studyctl.store.anchor import parse_head
from studyctl.store.integrity import verify_integrity
from studyctl.store.records import ERASE_ACTION, SEAL_ACTION
from studyctl.store.repository import StudyStore
from studyctl.store.workspace import resolve_database


def register(app: typer.Typer) -> None:
    audit_app = typer.Typer(help="Verify and show the append-only, hash-chained audit log.", no_args_is_help=True)

    @audit_app.command("verify")
    def verify(
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        head: str = typer.Option(None, "--head", help="A head noted earlier (ROWS:SHA256, as printed by run/resume): "
                                 "also check that the log still holds it."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object when the log is intact."),
        single_site: bool = typer.Option(False, "--single-site", help="PostgreSQL: every machine that writes this "
                                         "database keeps its head in the same head file (one machine, or "
                                         "STUDYCTL_AUDIT_HEAD_DIR on a folder they share), so audit rows after it "
                                         "are an error, not a note (as on SQLite)."),
    ) -> None:
        """Recompute the hash chain and every sealed record (trials, outcomes, events, answers, location reports,
        sample chunks); name every edited, deleted or inserted one and a truncated tail; exit non-zero if any."""
        noted = parse_head(head) if head is not None else None
        url, _ = resolve_database(db, workspace_arg(workspace))
        with StudyStore.open(url) as store:
            report = verify_integrity(store.db, noted, single_site=single_site)
        for note in report.notes:
            typer.echo(f"note: {note}", err=True)
        if report.ok:
            checked = report.records.summary()
            rows = report.audit.rows
            if as_json:
                typer.echo(json.dumps({"ok": True, "rows": rows, "head": f"{rows}:{report.audit.head_hash}",
                                       "records": checked, "erased": report.records.erased}))
                return
            erased = report.records.summary(tuple(report.records.erased), report.records.erased)
            typer.echo(f"Audit log intact: {rows} rows, head {rows}:{report.audit.head_hash}; "
                       f"records sealed and unchanged: {checked}"
                       + (f"; erased as audited: {erased}" if erased else ""))
            return
        for problem in report.problems:
            typer.echo(f"  {problem}", err=True)
        raise IntegrityError(f"the study database fails verification ({len(report.problems)} problem(s) above); "
                             "restore it from a backup and investigate who changed it")

    @audit_app.command("show")
    def show(
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        last: int = typer.Option(20, "--last", min=1, help="How many of the newest rows to show."),
        as_json: bool = typer.Option(False, "--json", help="Print JSON lines instead of text."),
        seals: bool = typer.Option(False, "--seals", help="Also show the records.seal rows (the digests of the "
                                   "records each transaction wrote; long) and the digests an erasure lists."),
    ) -> None:
        """Print the newest audit rows (time, actor, action, entity, details)."""
        url, _ = resolve_database(db, workspace_arg(workspace))
        with StudyStore.open(url) as store:
            frame = store.audit_frame()
        if not seals:
            frame = frame[frame.action != SEAL_ACTION]
        frame = frame.tail(last)
        for row in frame.itertuples(index=False):
            details = json.loads(row.details)
            if row.action == ERASE_ACTION and not seals:  # the erased records' digests: as long as a seal
                details.pop("erased", None)
            if as_json:
                typer.echo(json.dumps({"id": row.id, "at": row.at, "actor": row.actor, "action": row.action,
                                       "entity": row.entity, "entity_id": row.entity_id,
                                       "details": details}, ensure_ascii=False))
            else:
                text = row.details if row.action != ERASE_ACTION or seals else \
                    json.dumps(details, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
                typer.echo(f"{row.id:>6} {row.at} {row.actor} {row.action} {row.entity or ''}:{row.entity_id or ''} "
                           f"{text}")

    app.add_typer(audit_app, name="audit")
