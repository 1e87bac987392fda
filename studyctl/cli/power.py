"""``studyctl power``: power analysis by simulating the whole study many times (locally or on Dask)."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

from studyctl.cli.common import complete_shipped, output_console

_POP_HELP = ("A population file (format: studyctl-population/1) the virtual people are drawn from (default: the "
             "protocol's shipped population), or a YAML file with a population: section (baseline, "
             "condition_effects, group_effects, between_sd): additive shifts on top that state the simulated effect.")


def _is_trait_file(file: Path | None) -> bool:
    """Whether ``file`` is a studyctl-population/1 file (else: the knob file of earlier versions)."""
    if file is None or not file.is_file():
        return False
    from studyctl.populations.model import FORMAT

    head = file.read_text(encoding="utf-8", errors="replace")
    return any(line.split("#")[0].strip().replace('"', "").replace("'", "") == f"format: {FORMAT}"
               for line in head.splitlines())


def _population(file: Path | None, effects: list[str], group_effects: list[str], spreads: list[str],
                baselines: list[str]):  # noqa: ANN202 - Population, imported lazily
    from studyctl.power.population import Population, load_population, parse_knob

    pop = load_population(file) if file is not None else Population()
    cond: dict[str, dict[str, float]] = {}
    for text in effects:
        key, param, value = parse_knob(text, "--effect", keyed=True)
        cond.setdefault(str(key), {})[param] = value
    grp: dict[str, dict[str, float]] = {}
    for text in group_effects:
        key, param, value = parse_knob(text, "--group-effect", keyed=True)
        grp.setdefault(str(key), {})[param] = value
    sd = {p: v for _, p, v in (parse_knob(t, "--between-sd", keyed=False) for t in spreads)}
    base = {p: v for _, p, v in (parse_knob(t, "--baseline", keyed=False) for t in baselines)}
    return pop.merged(Population(base, cond, grp, sd))


def register(app: typer.Typer) -> None:
    @app.command("power")
    def power(
        protocol: str = typer.Argument(..., help="Protocol file, or a shipped protocol name (bio_inspired_palpation).",
                                       autocompletion=complete_shipped("protocols")),
        plan: str = typer.Option(None, "--plan", help="Analysis plan (file or shipped name) for that protocol "
                                 "(default for a shipped protocol: the shipped plan of the same name).",
                                 autocompletion=complete_shipped("analysis")),
        participants: str = typer.Option("8,12,16,20,25", "--participants", "-n",
                                         help="Sample sizes, comma-separated (each ≥ the counterbalancing sequences)."),
        replicates: int = typer.Option(500, "--replicates", "-r", help="Simulated studies per sample size."),
        seed: int = typer.Option(None, "--seed", "-s", help="Master seed (default: the protocol's study.seed)."),
        scheduler: str = typer.Option(None, "--scheduler",
                                      help="Address of an existing Dask scheduler (tcp://HOST:8786). "
                                           "Default: a local cluster of worker processes."),
        workers: int = typer.Option(None, "--workers",
                                    help="Local cluster: worker processes (default one per core; 0 = serial in this "
                                         "process). With --scheduler: workers to wait for (default 1)."),
        memory_limit: str = typer.Option("4GiB", "--memory-limit",
                                         help="Memory cap per worker (e.g. 2GiB; 0 = none)."),
        out: Path = typer.Option(Path("reports/power"), "--out", "-o",
                                 help="Report folder: power.csv, power_curve.png, the population, and the results "
                                      "file that makes an interrupted run continue where it stopped."),
        population: Path = typer.Option(None, "--population", help=_POP_HELP),
        effect: list[str] = typer.Option([], "--effect",
                                         help="CONDITION:PARAM=SHIFT added in that condition (repeatable), e.g. "
                                              "bio_inspired:balloon_weber=-0.03."),
        group_effect: list[str] = typer.Option([], "--group-effect",
                                               help="GROUP:PARAM=SHIFT added for that stratum (repeatable)."),
        between_sd: list[str] = typer.Option([], "--between-sd",
                                             help="PARAM=SD between-participant spread of a parameter (repeatable)."),
        baseline: list[str] = typer.Option([], "--baseline",
                                           help="PARAM=VALUE base value of a parameter (repeatable)."),
        show_posthoc: bool = typer.Option(False, "--posthoc", help="Also list post-hoc pairs in the printed table."),
        target: float = typer.Option(None, "--target",
                                     help="Target power in (0, 1), e.g. 0.8: report per test the smallest size run "
                                          "that reaches it (with its Wilson interval); every size must then "
                                          "complete the protocol's counterbalancing blocks."),
        two_stage: bool = typer.Option(False, "--two-stage/--exact",
                                       help="--two-stage: simulate a stored pool of virtual participants once (stage "
                                            "1, full engine) and draw every replicate study from it (stage 2: only "
                                            "the analysis plan runs); its error against full-engine replicates at "
                                            "--check-sizes is reported beside the power. --exact (default): every "
                                            "replicate through the full engine."),
        pool: int = typer.Option(None, "--pool", help="Two-stage: people in the pool (default and minimum: 20 × the "
                                                      "largest --participants)."),
        pool_dir: Path = typer.Option(Path("reports/power-pools"), "--pool-dir",
                                      help="Two-stage: folder of stored pools (keyed by protocol, plan, population "
                                           "sha256, seed; reused by later runs)."),
        check_sizes: str = typer.Option(None, "--check-sizes",
                                        help="Two-stage: sizes (a subset of --participants) at which full-engine "
                                             "replicates measure the design's error (default: the smallest)."),
        check_replicates: int = typer.Option(50, "--check-replicates",
                                             help="Two-stage: full-engine replicates per checked size (0: no check)."),
        pool_bootstrap: int = typer.Option(20, "--pool-bootstrap",
                                           help="Two-stage: bootstrap pools (the pool's people resampled) that "
                                                "measure the pool's own sampling error at --check-sizes, 50 stage-2 "
                                                "replicates each; that error is part of the comparison with the "
                                                "full engine (0: not measured)."),
        sim_rate_hz: float = typer.Option(
            None, "--sim-rate-hz",
            help="Run rate-adjustable feedback loops (the 1 kHz tissue and needle controllers) at most this fast "
                 "(default: 250 Hz where it slows a loop, as the demo and calibration do; what it changes: "
                 "`studyctl bench simrate`). Results and pools are kept apart by rate."),
        full_rate: bool = typer.Option(False, "--full-rate", help="Run every feedback loop at its protocol's rate "
                                                                  "(slower)."),
        as_json: bool = typer.Option(False, "--json", help="Print the results as one JSON document on stdout "
                                                           "(power table, target sizes, loop rates, files)."),
    ) -> None:
        """Estimate power per test and sample size by simulating the study with virtual participants.

        Each replicate enrolls N virtual participants into a throwaway in-memory database, runs their whole
        sessions through the real engine, and runs the analysis plan; power is the fraction of replicates
        in which a test is significant. Results are identical serially, locally or on a Dask cluster.
        """
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        from studyctl.analysis import load_plan
        from studyctl.protocol import load_protocol, resolve_protocol
        from studyctl.yamlmarks import precheck_yaml_file

        # the protocol and the plan read before the power stack (pandas, the engine, the statistics) is
        # imported: a hostile file is refused by a small process (issue 19); prepare_power checks the rest
        loaded_protocol = load_protocol(resolve_protocol(protocol))
        loaded_plan = None if plan is None else load_plan(plan)
        precheck_yaml_file(population, "population file")

        from studyctl.errors import SessionInterrupted
        from studyctl.power import prepare_power
        from studyctl.report.loop_rates import loop_rates_line
        from studyctl.report.power_figures import population_text
        from studyctl.workflows.power import run_power

        err = Console(stderr=True, highlight=False)
        console = err if as_json else output_console()
        from studyctl.populations import describe_choice

        if full_rate and sim_rate_hz is not None:
            from studyctl.errors import UsageError

            raise UsageError(f"--full-rate and --sim-rate-hz {sim_rate_hz:g} contradict each other: --full-rate runs "
                             "every loop at its protocol's rate; give one of them")
        if not full_rate and sim_rate_hz is None:
            from studyctl.engine.loop_rates import default_sim_rate

            sim_rate_hz = default_sim_rate(loaded_protocol)
        trait_file = _is_trait_file(population)
        pop = _population(None if trait_file else population, effect, group_effect, between_sd, baseline)
        spec = prepare_power(loaded_protocol, loaded_plan, sizes=participants, replicates=replicates, seed=seed,
                             population=pop, memory_limit=memory_limit,
                             traits=population if trait_file else "shipped", target=target,
                             sim_rate_hz=sim_rate_hz)
        console.print(describe_choice(spec.traits, spec.study_id, trait_file), markup=False)
        if plan is None:
            console.print(f"plan: the shipped analysis plan {spec.protocol_name!r} (the default for the shipped "
                          "protocol; --plan to choose another)", markup=False)
        sizes = ", ".join(map(str, spec.sizes))
        console.print(f"power: {spec.study_id}, plan {spec.plan.title!r}; participants {sizes}; "
                      f"{spec.replicates} replicates each; seed {spec.seed}", markup=False)
        console.print(population_text(spec.population), markup=False)
        console.print(loop_rates_line(spec.loop_rates(), spec.sim_rate_hz), markup=False)
        state = {"kept": 0}
        progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                            TimeRemainingColumn(), console=err, transient=False)
        task = progress.add_task("replicates", total=len(spec.tasks()))

        def on_progress(done: int, total: int, result) -> None:  # noqa: ANN001 - ReplicateResult | None
            if result is None:
                state["kept"] = done
                if done:
                    err.print(f"continuing: {done} of {total} replicates already in {out}", markup=False)
                # The bar appears once the workers are connected (an error before that stays one line).
                progress.start()
            else:
                progress.update(task, description=f"n={result.participants} r={result.replicate}")
            state["done"] = done
            progress.update(task, completed=done)

        if two_stage:
            from studyctl.workflows.power_two_stage import check_sizes_of, run_two_stage

            checks = check_sizes_of(spec, check_sizes)
            stages: dict[str, int] = {}

            def on_stage(stage: str, done: int, total: int) -> None:
                if stage not in stages:
                    progress.start()
                    stages[stage] = progress.add_task(stage, total=total)
                progress.update(stages[stage], completed=done)

            progress.remove_task(task)
            try:
                result = run_two_stage(spec, out, pool_dir=pool_dir, pool=pool, check_sizes=checks,
                                       check_replicates=check_replicates, boot_pools=pool_bootstrap,
                                       scheduler=scheduler, workers=workers,
                                       on_stage=on_stage)
            except KeyboardInterrupt:
                progress.stop()
                raise SessionInterrupted(
                    f"interrupted: the pool in {pool_dir} keeps every chunk finished so far and {out} every stage-2 "
                    "replicate; nothing half-written is kept; run the same command again to continue") from None
            finally:
                progress.stop()
            _done(console, result, show_posthoc, as_json)
            return
        try:
            result = run_power(spec, out, scheduler=scheduler, workers=workers, on_progress=on_progress,
                               on_backend=lambda d: err.print(f"running on: {d}", markup=False))
        except KeyboardInterrupt:
            progress.stop()
            # SessionInterrupted: the CLI prints it as one line and exits with 130, like an interrupted session.
            raise SessionInterrupted(f"interrupted: {state.get('done', 0)} of {len(spec.tasks())} replicates are "
                                     f"kept in {out}; run the same command again to continue") from None
        finally:
            progress.stop()
        _done(console, result, show_posthoc, as_json)


def _done(console: Console, result, show_posthoc: bool, as_json: bool) -> None:  # noqa: ANN001 - PowerRun
    """Print a finished run: one JSON document, or the tables and where the files are."""
    from studyctl.report.power_json import power_json
    from studyctl.report.terminal import power_table, target_table

    if as_json:
        import json
        import sys

        sys.stdout.write(json.dumps(power_json(result), indent=2, default=str) + "\n")
        return
    console.print(power_table(result, show_posthoc))
    if result.target is not None:
        console.print(target_table(result.target))
    if result.error is not None:
        e = result.error.summary()
        pool = ("pool error not measured (--pool-bootstrap 0): the SE leaves it out"
                if e["pool_se_pp_max"] != e["pool_se_pp_max"] else f"pool SE up to {e['pool_se_pp_max']:.1f} pp")
        console.print(f"two-stage error: max |two-stage - full engine| = {e['power_error_pp']:.1f} pp (SE "
                      f"{e['power_error_se_pp']:.1f}) at n = {', '.join(map(str, e['checked_sizes']))} "
                      f"({e['exact_replicates']} full-engine vs {e['two_stage_replicates']} two-stage replicates; MC "
                      f"SE up to {e['mc_se_exact_pp_max']:.1f} / {e['mc_se_two_stage_pp_max']:.1f} pp; {pool}; "
                      f"chi2 {e['chi2']:.1f} on {e['rows']} rows)", markup=False)
    if result.pool is not None:
        p = result.pool
        console.print(f"pool: {p['people']} people in {p['path']} ({p['chunks_built_now']} chunk(s) simulated now)",
                      markup=False)
    console.print(f"simulated {result.ran} replicate(s), reused {result.reused}, in {result.seconds:.1f} s "
                  f"({result.backend})", markup=False)
    for kind in ("table", "target", "error", "pool_error", "figure", "population", "replicates"):
        if kind in result.files:
            console.print(f"{kind}: {result.files[kind]}", markup=False)
