"""``studyctl run``, ``studyctl resume`` and ``studyctl export``: sessions and their data."""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from studyctl.cli.common import DB_OPTION, STUDY_OPTION, WORKSPACE_OPTION, workspace_arg

# The engine, the store and the view (SQLAlchemy, pandas, pyarrow: ~120 MB) are imported inside the commands, after
# a --input file was read: a hostile answers file is refused by a process that never loaded them.
if TYPE_CHECKING:
    from studyctl.engine.ui import Script
    from studyctl.store.workspace import OpenStudy

VIEW_OPTION = typer.Option(
    False, "--view", help="Also show the session on the participant's screen: serves the participant view on this "
    "machine and prints its URL (instructions, countdown, CT/cursor view, prompts; the terminal stays in control).")
VIEW_PORT_OPTION = typer.Option(0, "--view-port", help="Port of the participant view (default: a free one).")
LSL_OPTION = typer.Option(False, "--lsl", help="Also publish events (markers) and device samples to the Lab Streaming "
                          "Layer, to align with EEG/EMG/eye tracking (pip install 'studyctl\\[lsl]').")


class _Bar:
    """A rich progress bar over the plan's steps for long virtual or scripted runs (silent when not a tty)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        self.progress = None
        self.task = None

    def __enter__(self):
        if self.enabled:
            self.progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                     TimeElapsedColumn(), console=Console(stderr=True), transient=False)
            self.progress.__enter__()
            self.task = self.progress.add_task("session", total=None)
        return self

    def __call__(self, done: int, total: int, step) -> None:
        if self.progress is not None:
            self.progress.update(self.task, completed=done, total=total, description=step.label())

    def __exit__(self, *exc):
        if self.progress is not None:
            self.progress.__exit__(*exc)


JSON_OPTION = typer.Option(False, "--json", help="Print the result as one JSON object (messages go to stderr).")


def _summary(result, opened: OpenStudy, as_json: bool = False) -> None:
    from studyctl.store.anchor import audit_head  # noqa: PLC0415

    if as_json:
        head = audit_head(opened.store.db)
        typer.echo(json.dumps({**dataclasses.asdict(result), "audit_head": head.text()}, default=str))
        return
    typer.echo(f"Session {result.session_id} ({result.participant}): {result.status}; "
               f"{result.trials_completed} trials completed, {result.trials_aborted} aborted, "
               f"{result.trials_invalid} invalid, {result.answers} answers, {result.resumes} resume(s)")
    head = audit_head(opened.store.db)
    typer.echo(f"Audit head {head.text()} (note it in the lab notebook; `studyctl audit verify --head "
               f"{head.count}:…` checks the log still holds it)")


def _shipped_population(opened: OpenStudy, log: Callable[[str], None]) -> Any:
    """The protocol's shipped population (None when it has none), said on stderr as `simulate` says it."""
    from studyctl.store.enrollment import study_protocol  # noqa: PLC0415 (rehearsals only)
    from studyctl.workflows.simulate import choose_population  # noqa: PLC0415

    return choose_population(study_protocol(opened.study), say=log)


@contextmanager
def _live(db: str | None, workspace: Path | None, study: str | None, view: bool, view_port: int,
          bar_when: Callable[[OpenStudy], bool], quiet: bool = False) -> Iterator[tuple[OpenStudy, dict[str, Any]]]:
    """The open study and the keyword arguments run/resume share: progress bar, log to stderr, view front end
    (its address on stderr when ``quiet``: stdout then holds only the JSON result)."""
    from studyctl.store.workspace import open_study  # noqa: PLC0415
    from studyctl.view import open_view  # noqa: PLC0415

    announce = (lambda m: typer.echo(m, err=True)) if quiet else typer.echo
    with open_study(db, workspace_arg(workspace), study) as opened, \
            open_view(view, port=view_port, announce=announce) as pv, _Bar(bar_when(opened)) as bar:
        yield opened, {"progress": bar, "log": lambda m: typer.echo(m, err=True),
                       "frontend": pv.attach if pv else None}


def _script(path: Path | None) -> Script | None:
    """The --input file read and checked before anything heavy is imported or any database opened."""
    if path is None:
        return None
    from studyctl.engine.ui import Script  # noqa: PLC0415

    return Script.load(path)


INPUT_HELP = (
    "Scripted answers (YAML or JSON) for a rehearsal or test run without a terminal. Keys, all optional: "
    "trials: {TRIAL_NUMBER: \\[{t: SECONDS, request: scan|report|finish, answer: 'C 3'}]} (requests at trial time t); "
    "likert: {ITEM_ID: \\[code, ...]} or {INSTRUMENT_ID: {ITEM_ID: \\[...]}} (used in order); default_likert: CODE; "
    "outcomes: \\[{duration_s: S, reports: \\['C 3']}] (manual trials, in order); "
    "controls: \\[{trial: N, t: S, action: abort|pause|invalid|note, reason: TEXT}] (a note's text is its reason); "
    "familiarisation: end_early|full. See README 'Rehearsals and scripted sessions'."
)


def register(app: typer.Typer) -> None:
    @app.command("run")
    def run(
        participant: str = typer.Option(..., "--participant", "-p", help="Participant code (from `studyctl enroll`)."),
        virtual: bool = typer.Option(False, "--virtual", help="Run the protocol's virtual participant (simulated "
                                     "device and clock) instead of a person. With --rehearse it acts on the "
                                     "emulated hardware instead (its hand in the emulator's world; real time)."),
        seed: int = typer.Option(None, "--seed", help="Session seed (default: from the study seed and the code)."),
        input_file: Path = typer.Option(None, "--input", help=INPUT_HELP),
        rehearse: bool = typer.Option(False, "--rehearse", help="A rehearsal: every hardware device is replaced by "
                                      "its emulator (started and stopped here, in its own process); recorded in the "
                                      "study marked as rehearsal and left out of analysis. With a person at the "
                                      "prompts, a script (--input), or the virtual participant (--virtual)."),
        speed: float = typer.Option(None, "--speed", help="Virtual/scripted runs: at most this many times real "
                                    "time (default: as fast as possible; hardware trials always run in real time)."),
        view: bool = VIEW_OPTION,
        view_port: int = VIEW_PORT_OPTION,
        lsl: bool = LSL_OPTION,
        as_json: bool = JSON_OPTION,
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
    ) -> None:
        """Run a participant's session: instructions, practice, trials, breaks and questionnaires."""
        script = _script(input_file)
        from studyctl.engine.api import run_session  # noqa: PLC0415

        unattended = virtual or input_file is not None
        with _live(db, workspace, study, view, view_port, lambda _: unattended, as_json) as (opened, hooks):
            # a virtual rehearsal rehearses with a person of the protocol's population, as `simulate` draws them
            population = _shipped_population(opened, hooks["log"]) if rehearse and virtual else None
            result = run_session(opened.store, participant, study=opened.study.name, virtual=virtual, seed=seed,
                                 script=script, speed=speed, rehearse=rehearse, lsl=lsl, population=population,
                                 **hooks)
            _summary(result, opened, as_json)

    @app.command("resume")
    def resume(
        session: int = typer.Argument(..., help="Session id to continue (shown by `studyctl status`)."),
        input_file: Path = typer.Option(None, "--input", help="Scripted answers (YAML/JSON) for the rest of the "
                                        "session (person sessions without a terminal)."),
        speed: float = typer.Option(None, "--speed", help="Virtual/scripted sessions: at most this many times real "
                                    "time (default: as fast as possible)."),
        take_over: bool = typer.Option(False, "--take-over", help="Take the session over from the process that "
                                       "last held it, when that process is gone (crashed or killed on this "
                                       "machine, a closed PostgreSQL connection, or another host with no heartbeat "
                                       "for 30 s); audited. Never from a process that still runs."),
        view: bool = VIEW_OPTION,
        view_port: int = VIEW_PORT_OPTION,
        lsl: bool = LSL_OPTION,
        as_json: bool = JSON_OPTION,
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
    ) -> None:
        """Continue an interrupted session from its stored plan (crash, kill, Ctrl-C or device fault)."""
        script = _script(input_file)
        from studyctl.engine.api import resume_session, session_is_virtual  # noqa: PLC0415

        bar_when = lambda opened: input_file is not None or session_is_virtual(opened.store, session)  # noqa: E731
        with _live(db, workspace, study, view, view_port, bar_when, as_json) as (opened, hooks):
            result = resume_session(opened.store, session, script=script, speed=speed, take_over=take_over,
                                    lsl=lsl, **hooks)
            _summary(result, opened, as_json)

    @app.command("export")
    def export(
        folder: Path = typer.Argument(..., help="New or empty folder for the tables, data_dictionary.json and "
                                      "datapackage.json."),
        fmt: str = typer.Option("csv", "--format", help="csv, or parquet (typed, zstd-compressed columns)."),
        samples: bool = typer.Option(True, "--samples/--no-samples", help="Also write samples.csv (large)."),
        process_info: bool = typer.Option(False, "--process-info", help="Keep host names and process ids (where "
                                          "each session ran) in events.csv; left out by default."),
        as_json: bool = JSON_OPTION,
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
    ) -> None:
        """Export trials, events, responses, reports and samples as tidy tables with a data dictionary and a
        Frictionless data package."""
        from studyctl.engine.export import export_study  # noqa: PLC0415
        from studyctl.store.workspace import open_study  # noqa: PLC0415

        with open_study(db, workspace_arg(workspace), study) as opened:
            result = export_study(opened.store, folder, study=opened.study.name, samples=samples,
                                  process_info=process_info, format=fmt)
        if as_json:
            typer.echo(json.dumps({"folder": str(folder), "format": fmt, "rows": result.rows,
                                   "metadata": ["data_dictionary.json", "datapackage.json"]}))
            return
        for name, n in sorted(result.rows.items()):
            typer.echo(f"{folder / name}: {n} rows")
        typer.echo(f"{folder / 'data_dictionary.json'}: every column with its unit")
        typer.echo(f"{folder / 'datapackage.json'}: Frictionless data package (schema, units, descriptions)")
