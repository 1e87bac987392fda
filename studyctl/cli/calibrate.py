"""``studyctl calibrate``: fit a virtual population to published (or pilot) numbers."""

from __future__ import annotations

from pathlib import Path

import typer

from studyctl.cli.common import complete_shipped
from studyctl.engine.loop_rates import SIM_RATE_HZ


def register(app: typer.Typer) -> None:
    @app.command("calibrate")
    def calibrate(
        protocol: str = typer.Argument(..., help="Shipped protocol name or protocol file.",
                                       autocompletion=complete_shipped("protocols")),
        targets: Path = typer.Option(None, "--targets", help="Targets file (format: studyctl-targets/1; default: "
                                     "the protocol's shipped studyctl/populations/<protocol>.targets.yaml)."),
        population: Path = typer.Option(None, "--population", help="Population to start from (default: the "
                                        "protocol's shipped population)."),
        free: str = typer.Option(None, "--free", help="Free parameters, comma-separated: TRAIT (its mean/median), "
                                 "TRAIT.sd, TRAIT@GROUP, or a fixed parameter (default: calibration.free of the "
                                 "population file)."),
        seed: int = typer.Option(1, "--seed", "-s", help="Seed of the simulated studies (the same for every "
                                 "candidate: common random numbers)."),
        participants: int = typer.Option(None, "--participants", "-n", help="People per simulated study in each "
                                         "evaluation (default 4; the fitted population is then run once at the "
                                         "protocol's target_n)."),
        replicates: int = typer.Option(2, "--replicates", help="Simulated studies per evaluation (different "
                                       "seeds, the same for every candidate)."),
        workers: int = typer.Option(None, "--workers", help="Local worker processes for the replicate studies "
                                    "(default: min(replicates, CPU cores))."),
        sim_rate_hz: float = typer.Option(SIM_RATE_HZ, "--sim-rate-hz", help="Loop rate of rate-adjustable "
                                          "controllers (the 1 kHz tissue and needle loops), as `studyctl demo` runs "
                                          "them."),
        evaluations: int = typer.Option(24, "--evaluations", help="Candidate populations to try (the optimiser's "
                                        "budget), besides the ±h profile of each free parameter."),
        scheduler: str = typer.Option(None, "--scheduler", help="Dask scheduler address: run each evaluation's "
                                      "replicate studies on its workers."),
        pilot_db: str = typer.Option(None, "--pilot-db", help="A pilot study's database (SQLite file or URL): "
                                     "targets from its data instead of a paper (with --targets: the same "
                                     "targets, values from the pilot)."),
        out: Path = typer.Option(None, "--out", "-o", help="Population file to write (default: "
                                 "./<protocol>.calibrated.yaml); the fit report and the journal go beside it."),
        as_json: bool = typer.Option(False, "--json", help="Print the result as one JSON document on stdout "
                                     "(estimates with SEs, every target's agreement, fit and validation "
                                     "summaries, what was missed, time, files); the readable lines go to stderr."),
    ) -> None:
        """Fit a population's free parameters so simulated studies match published targets (resumable)."""
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        # every input checked before the simulation stack (pandas, the engine) is imported: a hostile targets
        # or protocol file is refused by a small process (issue 19)
        from studyctl.workflows.calibration_spec import prepare_calibration
        from studyctl.yamlmarks import precheck_yaml_file

        precheck_yaml_file(population, "population file")

        err = Console(stderr=True, highlight=False)
        console = err if as_json else Console(highlight=False)
        spec = prepare_calibration(protocol, targets, population=population, free=free, seed=seed,
                                   participants=participants, replicates=replicates, evaluations=evaluations,
                                   out=out, scheduler=scheduler, pilot_db=pilot_db, workers=workers,
                                   sim_rate_hz=sim_rate_hz)
        from studyctl.workflows.calibrate import run_calibration

        console.print(f"calibrate {spec.protocol_id}: from {spec.population.label}; targets {spec.targets.path} "
                      f"({len(spec.targets.by_role('fit'))} fit, {len(spec.targets.by_role('validation'))} "
                      f"validation); free {', '.join(f.name for f in spec.free)}; {spec.evaluations} evaluations of "
                      f"{spec.replicates} × {spec.participants} people (seed {spec.seed})", markup=False)
        if spec.journal.exists():
            err.print(f"continuing from the journal {spec.journal}", markup=False)
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=err) as progress:
            task = progress.add_task("calibrating", total=None)
            result = run_calibration(spec, on_progress=lambda i, n, m: progress.update(
                task, completed=i, total=n, description=m))
        console.print(f"distance over the fit targets: {result.start_distance:.3g} → {result.best_distance:.3g} "
                      f"({result.evaluations} evaluations, {result.reused} from the journal; "
                      f"{result.seconds:.0f} s wall, {result.cpu_seconds:.0f} s CPU)", markup=False)
        for e in result.estimates:
            se = f"± {e.se:.3g}" if e.se != float("inf") else "(flat)"
            flag = "" if e.identified else "   NOT IDENTIFIED by these targets"
            console.print(f"  {e.name}: {e.start:.4g} → {e.estimate:.4g} {se}{flag}", markup=False)
        if any(e.profile_rise < 0 for e in result.estimates):
            console.print("  not converged: a profile step lowered the distance; run again with more --evaluations",
                          markup=False)
        summ = result.agreement.summary()
        for role in ("fit", "validation"):
            s = summ[role]
            if s["targets"]:
                frac = "–" if s["agree_fraction"] is None else f"{s['agree_fraction']:.0%}"
                console.print(f"  {role} targets at the paper's size ({spec.paper_participants}): {frac} agree "
                              f"({s['agree_n']} checked)", markup=False)
        if result.missed:
            console.print(f"missed {len(result.missed)} fit target(s):", markup=False)
            for m in result.missed:
                console.print(f"  {m}", markup=False)
        for kind, path in result.files.items():
            console.print(f"{kind}: {path}", markup=False)
        if as_json:
            import json
            import sys

            from studyctl.populations import load_population_file
            from studyctl.report.calibration import calibration_json

            sha = load_population_file(result.population_file).sha256
            sys.stdout.write(json.dumps(calibration_json(result, sha), indent=2, default=str) + "\n")
