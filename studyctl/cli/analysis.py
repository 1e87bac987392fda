"""``studyctl analyze``, ``studyctl report``, ``studyctl simulate`` and ``studyctl demo``."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console

from studyctl.cli.common import (
    DB_OPTION,
    PIPED_WIDTH,
    STUDY_OPTION,
    WORKSPACE_OPTION,
    complete_shipped,
    output_console,
    workspace_arg,
)
from studyctl.engine.loop_rates import SIM_RATE_HZ
from studyctl.resources import shipped_names


def _console(err: bool = False) -> Console:
    return output_console(stderr=err)


def register(app: typer.Typer) -> None:
    @app.command("analyze")
    def analyze(
        plan: str = typer.Argument(..., help="Analysis plan file, or a shipped plan name (e.g. needle_insertion).",
                                  autocompletion=complete_shipped("analysis")),
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
        as_json: bool = typer.Option(False, "--json", help="Print the tests table as JSON records."),
        check: bool = typer.Option(False, "--check", help="Only validate the plan (every problem, file:line)."),
    ) -> None:
        """Run an analysis plan on a study database (or its summary CSV) and print the tests table."""
        from studyctl.analysis import load_plan

        loaded = load_plan(plan)  # before the statistics stack is imported: a bad plan costs little to refuse
        if check:
            typer.echo(
                f"{loaded.source_path}: OK ({len(loaded.metrics)} metrics, {len(loaded.tests)} tests, "
                f"{len(loaded.figures)} figures)"
            )
            return
        from studyctl.analysis import analyze as run_analysis

        result = run_analysis(loaded, db=db, workspace=workspace_arg(workspace), study=study)
        if as_json:
            typer.echo(result.to_frame().to_json(orient="records"))
        else:
            from studyctl.report.terminal import analysis_tables

            console = _console()
            piped = console.width == PIPED_WIDTH  # a pipe or file: whole notes, not cut at 40 characters
            for table in analysis_tables(result, notes_width=None if piped else 40):
                console.print(table)
                console.print()
        if result.partial:
            err = _console(err=True)
            err.print("[bold yellow]PARTIAL RESULTS[/]: some of what the plan asks for could not be computed:")
            for p in result.problems:
                err.print(f"  - {p}", markup=False)

    @app.command("report")
    def report(
        plan: str = typer.Argument(..., help="Analysis plan file, or a shipped plan name.",
                                  autocompletion=complete_shipped("analysis")),
        out: Path = typer.Option(..., "--out", "-o", help="Folder for tables, figures, report.html and report.md."),
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
        targets: Path = typer.Option(None, "--targets", help="Published targets a simulated study is compared "
                                     "with (default: the protocol's shipped studyctl/populations/<protocol>"
                                     ".targets.yaml)."),
        figure_format: str = typer.Option("png,svg,pdf", "--figure-format", help="Figure files to write, "
                                          "comma-separated: png (300 dpi), svg, pdf."),
        as_json: bool = typer.Option(False, "--json", help="Print the files written (and any problems) as one "
                                     "JSON object."),
    ) -> None:
        """Analyse a plan and write tidy CSV tables, figures, an HTML report and Markdown into a folder."""
        from studyctl.analysis import load_plan

        loaded = load_plan(plan)  # before the statistics and figures are imported: a bad plan costs little to refuse
        from studyctl.workflows.report import build_report

        console = _console()
        with _console(err=True).status("analysing…") as status:
            run = build_report(
                loaded,
                out,
                db=db,
                workspace=workspace_arg(workspace),
                study=study,
                on_step=lambda s: status.update(f"{s}…"),
                targets=targets,
                figure_formats=tuple(figure_format.split(",")),
            )
        files = run.files
        if as_json:
            typer.echo(json.dumps({"html": str(files.html), "markdown": str(files.markdown),
                                   "tables": [str(t) for t in files.tables], "figures": [str(f) for f in files.figures],
                                   "partial": files.partial, "problems": list(files.problems)}))
            return
        console.print(f"Report: {files.html}", markup=False)
        console.print(
            f"        {files.markdown}  ({len(files.tables)} tables, {len(files.figures)} figures)", markup=False
        )
        if files.partial:
            err = _console(err=True)
            err.print("[bold yellow]PARTIAL RESULTS[/] (also marked in the report):")
            for p in files.problems:
                err.print(f"  - {p}", markup=False)

    register_sim(app)


def register_sim(app: typer.Typer) -> None:
    @app.command("simulate")
    def simulate(
        protocol: str = typer.Argument(..., help="Shipped protocol name or protocol file.",
                                      autocompletion=complete_shipped("protocols")),
        participants: int = typer.Option(..., "--participants", "-n", help="How many virtual participants."),
        seed: int = typer.Option(..., "--seed", "-s", help="Master seed of the study (same seed, same data)."),
        out: Path = typer.Option(None, "--out", "-o", help="New workspace folder (default: ./<protocol>-sim)."),
        db: str = typer.Option(None, "--db", help="PostgreSQL URL to hold the study instead of a study.db file."),
        durable: bool = typer.Option(
            False, "--durable", help="fsync every commit, as for real sessions (slower; simulations are re-creatable)."
        ),
        sim_rate_hz: float = typer.Option(
            None,
            "--sim-rate-hz",
            help="Run rate-adjustable feedback loops (the 1 kHz tissue and needle controllers) at most this fast: "
            "faster simulation, outcomes as measured by `studyctl bench simrate` (default: the protocol's rates).",
        ),
        population: Path = typer.Option(
            None, "--population", help="Population file the virtual people are drawn from (default: the "
            "protocol's shipped population, studyctl/populations/<protocol>.yaml, when there is one)."),
        as_json: bool = typer.Option(False, "--json", help="Print the result (workspace, database, counts, "
                                     "seconds, population) as one JSON object."),
    ) -> None:
        """Run seeded virtual participants through the real engine into a new study workspace."""
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from studyctl.protocol import load_protocol, resolve_protocol
        from studyctl.yamlmarks import precheck_yaml_file

        # the protocol (and population) read before the engine and the store are imported: a hostile file is
        # refused by a small process (issue 19); check_simulation checks the rest
        proto = load_protocol(resolve_protocol(protocol))
        precheck_yaml_file(population, "population file")
        from studyctl.workflows.simulate import check_simulation, choose_population, loop_rates_note, simulate_study

        folder = out or Path(f"{Path(protocol).stem}-sim")
        # Every input checked before the progress bar starts: a mistake is one Error line, nothing else.
        check_simulation(protocol, participants, sim_rate_hz, out_dir=folder, db=db)
        if sim_rate_hz is not None:  # what the cap did, in power's words (the protocol's rates if it slowed nothing)
            typer.echo(loop_rates_note(proto, sim_rate_hz), err=True)
        pop = choose_population(proto, population, say=lambda line: typer.echo(line, err=True))
        with Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn("{task.fields[code]}"),
            console=_console(err=True),
        ) as progress:
            task = progress.add_task(f"simulating {Path(protocol).stem}", total=participants, code="")
            result = simulate_study(
                protocol,
                participants,
                seed,
                folder,
                db=db,
                durable=durable,
                sim_rate_hz=sim_rate_hz,
                on_progress=lambda i, n, code: progress.update(task, completed=i, code=code),
                population=pop,
            )
        if as_json:
            from dataclasses import asdict

            typer.echo(json.dumps(asdict(result)))
            return
        typer.echo(
            f"Simulated {result.participants} participants of {result.study!r} in {result.seconds:.1f} s: "
            f"{result.trials_completed} trials completed, {result.trials_not_completed} not"
        )
        typer.echo(f"  workspace: {result.workspace}")
        typer.echo(f"  database:  {result.database}")
        # A shipped protocol has a shipped analysis plan of the same name; a protocol file of one's own does not.
        plans = shipped_names("analysis")
        stem = Path(protocol).stem
        typer.echo(
            f"  next:      studyctl report {stem if stem in plans else 'PLAN.yaml'} --workspace {result.workspace} "
            f"--out {result.workspace}/report"
        )
        if stem not in plans:
            typer.echo(f"             (no shipped analysis plan is named {stem!r}: write PLAN.yaml for this protocol, "
                       f"starting from one of the shipped plans: {', '.join(plans)})")

    @app.command("demo")
    def demo(
        out: Path = typer.Option(Path("reports"), "--out", "-o", help="Folder for the four reports and index.html."),
        seed: int = typer.Option(2024, "--seed", "-s", help="Master seed of all four studies."),
        workers: int = typer.Option(None, "--workers", help="Parallel worker processes (default: CPU cores)."),
        as_json: bool = typer.Option(False, "--json", help="Print the per-study summary as JSON."),
        sim_rate_hz: float = typer.Option(
            SIM_RATE_HZ,
            "--sim-rate-hz",
            help="Loop rate of the simulated 1 kHz tissue and needle controllers (physics stays at the device's rate); "
            "`studyctl bench simrate` shows what it changes.",
        ),
        full_rate: bool = typer.Option(
            False, "--full-rate", help="Run every feedback loop at its protocol's rate (slower)."
        ),
    ) -> None:
        """Simulate the four reference studies (paper-sized), analyse them and write their reports."""
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from studyctl.engine.loop_rates import check_sim_rate
        from studyctl.workflows.demo import REFERENCE_STUDIES, run_demo

        if not full_rate:
            check_sim_rate(sim_rate_hz)  # before any progress bar
        err = _console(err=True)
        with Progress(
            TextColumn("{task.description:<26}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn("{task.fields[stage]}"),
            console=err,
        ) as progress:
            tasks = {name: progress.add_task(name, total=n, stage="waiting") for name, n in REFERENCE_STUDIES}

            def on_event(event) -> None:  # noqa: ANN001
                study, stage, done, total, message = event
                task = tasks[study]
                if stage == "simulate":
                    progress.update(task, completed=done, total=total, stage=f"simulating {message}")
                elif stage == "analyse":
                    progress.update(task, stage=f"analysing: {message}")
                else:
                    progress.update(
                        task,
                        completed=progress.tasks[task].total,
                        stage=stage if stage != "failed" else f"FAILED: {message[:60]}",
                    )

            result = run_demo(
                out, seed=seed, workers=workers, sim_rate_hz=None if full_rate else sim_rate_hz, on_event=on_event
            )
        if as_json:
            typer.echo(result.to_frame().to_json(orient="records"))
        else:
            console = _console()
            from studyctl.report.terminal import demo_table

            console.print(demo_table(result))
            for r in result.studies:
                if r.population:
                    console.print(f"  {r.study}: {r.population}", markup=False)
                for line in r.headline:
                    console.print(f"  {r.study}: {line}", markup=False)
                if r.error:
                    err.print(f"  {r.study} FAILED: {r.error.splitlines()[0]}", markup=False)
            console.print(f"Reports: {result.index}", markup=False)
        if not result.ok:
            raise typer.Exit(1)
