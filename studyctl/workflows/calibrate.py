"""``studyctl calibrate``: fit a population's free parameters so simulated studies match published targets.

Simulated method of moments with common random numbers:

1. every candidate population is run as the same ``replicates`` simulated studies of ``participants`` people
   (the same seeds for every candidate: the same enrolment, placements, session seeds and per-person standard
   normals — only the population's numbers differ), through the real engine, controllers, devices and scenes
   (:func:`studyctl.power.replicate.simulate_replicate`), and the plan's metrics and tests are computed;
2. the distance (:func:`studyctl.calibration.distance`) over the ``fit`` targets — weights from the published
   uncertainty plus the simulation's own bootstrap SE at the starting values — is minimised by Optuna's TPE
   sampler (seeded); every evaluation is journaled next to the output (Optuna's journal file), so a rerun of
   the same command continues where the last one stopped;
3. around the best point each free parameter is moved by ±h (15 % of its search range): the curvature gives its
   standard error (the profile weighs the targets by the simulation's bootstrap SE at the best point, not at
   the start), and a profile that rises by less than 1 is reported as not identified by the targets; a
   profile point lower than the best (the search had not converged) becomes the best and is profiled again
   (at most :data:`RECENTRE` times);
4. the fitted population is run once at the paper's sample size (the protocol's ``target_n``) for the fit
   report: every target, fit and validation, against its simulated value with a bootstrap interval.

Nothing here fits an outcome: the free parameters are perception/behaviour traits of the virtual people.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pandas as pd

from studyctl.calibration import agreement, distance
from studyctl.calibration.simulated import stats_from_frame
from studyctl.workflows.calibration_runs import FAILED_DISTANCE, Evaluation, close_pools, dask_client, evaluate
from studyctl.workflows.calibration_spec import SIGMA0, CalibrationSpec, prepare_calibration

__all__ = [
    "CalibrationResult", "CalibrationSpec", "ParamEstimate", "evaluate", "fitted_population", "prepare_calibration",
    "run_calibration",
]

PROFILE_STEP = 0.15  # ±h as a fraction of each free parameter's search range
RECENTRE = 2  # times the best may move to a lower profile point and be profiled again
ProgressFn = Callable[[int, int, str], None]


# ------------------------------------------------------------------------------------------ the fit


@dataclass(frozen=True)
class ParamEstimate:
    name: str
    start: float
    estimate: float
    se: float
    low: float
    high: float
    profile_rise: float  # smallest rise of the distance at ±h
    identified: bool
    scale: str

    def to_dict(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class CalibrationResult:
    spec: CalibrationSpec
    start_distance: float
    best_distance: float
    estimates: tuple[ParamEstimate, ...]
    final: Evaluation  # the fitted population at the paper's sample size
    agreement: Any  # studyctl.calibration.Agreement of the final run
    evaluations: int
    reused: int  # evaluations (search, profile) taken from the journal instead of run again
    seconds: float  # wall time of this run
    cpu_seconds: float  # CPU time of every evaluation, including those in the journal, and the paper-size run
    population_file: Path
    optimiser: str = ""
    files: dict[str, Path] = field(default_factory=dict)
    missed: tuple[str, ...] = ()

    def to_frame(self) -> pd.DataFrame:
        """One row per target: the agreement table of the final run."""
        return self.agreement.to_frame()


def _journal_storage(path: Path) -> Any:
    import optuna
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return JournalStorage(JournalFileBackend(str(path)))


def _as_search(spec: CalibrationSpec, values: dict[str, float]) -> dict[str, float]:
    return {f.name: f.to_search(values[f.name]) for f in spec.free}


def _from_trial(spec: CalibrationSpec, params: dict[str, float]) -> dict[str, float]:
    return {f.name: f.from_search(params[f.name]) for f in spec.free}


def run_calibration(spec: CalibrationSpec, *, on_progress: ProgressFn | None = None) -> CalibrationResult:
    """Fit, profile, run the fitted population at paper size, and write the files (see the module docs)."""

    client = dask_client(spec.scheduler)
    try:
        return _run(spec, client, on_progress)
    finally:
        if client is not None:
            client.close()
        close_pools()


def _run(spec: CalibrationSpec, client: Any, on_progress: ProgressFn | None) -> CalibrationResult:
    import optuna

    t0 = time.perf_counter()
    spec.out.parent.mkdir(parents=True, exist_ok=True)
    storage = _journal_storage(spec.journal)
    distributions = {
        f.name: optuna.distributions.FloatDistribution(*f.search_bounds) for f in spec.free
    }
    study = optuna.create_study(
        study_name=f"calibrate-{spec.protocol_id}-{spec.fingerprint()}", storage=storage, direction="minimize",
        load_if_exists=True,
        sampler=_sampler(spec),
    )
    done = [t for t in study.get_trials(deepcopy=False) if t.state == optuna.trial.TrialState.COMPLETE]
    reused = len(done)
    total = spec.evaluations + 2 * len(spec.free) + 1
    progress = on_progress or (lambda i, n, m: None)
    cpu = sum(float(t.user_attrs.get("cpu_seconds", 0.0)) for t in done)

    def record(trial: Any, phase: str, ev: Evaluation, dist: float, z: dict[str, float]) -> None:
        trial.set_user_attr("phase", phase)
        trial.set_user_attr("values", ev.values)
        trial.set_user_attr("z", {k: (None if not math.isfinite(v) else v) for k, v in z.items()})
        trial.set_user_attr("stats", json.loads(ev.stats.to_json(orient="records")))
        trial.set_user_attr("seconds", ev.seconds)
        trial.set_user_attr("cpu_seconds", ev.cpu_seconds)
        study.tell(trial, dist)

    def run_trial(trial: Any, phase: str, sim_se: dict[str, float]) -> Evaluation:
        ev = evaluate(spec, _from_trial(spec, trial.params), sim_se=sim_se, client=client)
        record(trial, phase, ev, ev.distance, ev.z)
        return ev

    start_vals = {f.name: f.value for f in spec.free}
    first = next((t for t in done if t.user_attrs.get("phase") == "start"), None)
    if first is None:
        progress(0, total, "starting values")
        study.enqueue_trial(_as_search(spec, start_vals))
        trial = study.ask(distributions)
        ev = evaluate(spec, _from_trial(spec, trial.params), client=client)
        # weights: the simulation's own bootstrap SE at the starting values, kept for every candidate
        sim_se = {r.target: (r.se if math.isfinite(r.se) else 0.0) for r in stats_from_frame(ev.stats).values}
        start_distance, z = distance(spec.fit_targets, stats_from_frame(ev.stats), spec.targets.alpha, sim_se)
        trial.set_user_attr("sim_se", sim_se)
        record(trial, "start", ev, start_distance, z)
        cpu += ev.cpu_seconds
    else:
        sim_se = dict(first.user_attrs["sim_se"])
        start_distance = float(first.value)
    complete = optuna.trial.TrialState.COMPLETE
    n_search = len([t for t in study.get_trials(deepcopy=False)
                    if t.state == complete and t.user_attrs.get("phase") in ("start", "search")])
    while n_search < spec.evaluations:
        progress(n_search, total, f"evaluation {n_search + 1} of {spec.evaluations}")
        trial = study.ask(distributions)
        ev = run_trial(trial, "search", sim_se)
        cpu += ev.cpu_seconds
        n_search += 1
    searched = [t for t in study.get_trials(deepcopy=False) if t.state == optuna.trial.TrialState.COMPLETE
                and t.user_attrs.get("phase") in ("start", "search")]
    best = min(searched, key=lambda t: t.value)
    best_u = dict(best.params)
    # The profile weighs each target by the simulation's bootstrap SE at the best candidate, not at the starting
    # values (a start far off, e.g. slow people with widely spread times, would make every profile look flat):
    # the SE of an estimate is the spread of the statistics there. Distances are recomputed from the journaled
    # statistics of each evaluation, so nothing is simulated again for the new weights.
    profile_se = {r.target: (r.se if math.isfinite(r.se) else 0.0)
                  for r in stats_from_frame(best.user_attrs["stats"]).values}

    def reweigh(trial: Any) -> float:
        return distance(spec.fit_targets, stats_from_frame(trial.user_attrs["stats"]), spec.targets.alpha,
                        profile_se)[0]

    best_value = reweigh(best)

    def point(u: dict[str, float], label: str) -> float:
        """The distance (profile weights) at search point ``u``, from the journal when already run."""
        nonlocal cpu
        prior = next((t for t in study.get_trials(deepcopy=False)
                      if t.state == optuna.trial.TrialState.COMPLETE and t.user_attrs.get("phase") == "profile"
                      and all(abs(t.params[n] - u[n]) < 1e-12 for n in u)), None)
        if prior is not None:
            return reweigh(prior)
        progress(min(done_steps[0], total - 2), total, label)
        done_steps[0] += 1
        study.enqueue_trial(u)
        trial = study.ask(distributions)
        ev = run_trial(trial, "profile", sim_se)
        cpu += ev.cpu_seconds
        # the statistics as journaled (JSON keeps 10 digits), so a rerun computes the very same distance
        journaled = json.loads(ev.stats.to_json(orient="records"))
        return distance(spec.fit_targets, stats_from_frame(journaled), spec.targets.alpha, profile_se)[0]

    # profile: ±h along each free parameter (journaled like the search, so a rerun reuses them). A profile
    # point below the best candidate means the search had not converged: the best moves there and the profile
    # is taken again around it (at most RECENTRE times); a point still lower after that is reported.
    done_steps = [spec.evaluations]
    for _round in range(RECENTRE + 1):
        estimates, lowest = [], (best_value, None)
        for f in spec.free:
            lo_u, hi_u = f.search_bounds
            h = PROFILE_STEP * (hi_u - lo_u)
            rises, pts = [], {}
            for sign in (-1, 1):
                u = dict(best_u)
                u[f.name] = min(max(best_u[f.name] + sign * h, lo_u), hi_u)
                value = point(u, f"profile {f.name} {'-' if sign < 0 else '+'}h")
                pts[sign] = (u[f.name] - best_u[f.name], value)
                rises.append(value - best_value)
                if value < lowest[0]:
                    lowest = (value, u)
            (dm, fm), (dp, fp) = pts[-1], pts[1]
            se_u = math.inf
            if dm < 0 < dp:
                # second derivative of a parabola through the three points
                curv = 2 * ((fp - best_value) / dp - (fm - best_value) / dm) / (dp - dm)
                if curv > 1e-9:  # below: a flat profile (rounding of the journaled statistics)
                    se_u = math.sqrt(2.0 / curv)
            est = f.from_search(best_u[f.name])
            deriv = abs(f.from_search(best_u[f.name] + 1e-6) - est) / 1e-6
            rise = min(rises)
            estimates.append(ParamEstimate(f.name, f.value, est, se_u * deriv, f.low, f.high, rise, rise >= 1.0,
                                           f.scale))
        if lowest[1] is None or _round == RECENTRE:
            break
        best_value, best_u = lowest[0], dict(lowest[1])
        total += 2 * len(spec.free)
    # the objective at the fitted values, in the search's weights (comparable with the start's)
    fitted_trial = next((t for t in study.get_trials(deepcopy=False)
                         if t.state == optuna.trial.TrialState.COMPLETE and t.value is not None
                         and all(abs(t.params[n] - best_u[n]) < 1e-12 for n in best_u)), best)
    best_distance = float(fitted_trial.value)

    # the fitted population at the paper's sample size: every target
    progress(total - 1, total, f"fitted population at the paper's size ({spec.paper_participants} people)")
    fitted_values = _from_trial(spec, best_u)
    final = _final_run(spec, fitted_values, client)
    cpu += final.cpu_seconds
    agr = agreement(spec.targets.targets, stats_from_frame(final.stats), spec.targets.alpha)
    missed = _missed(agr)
    progress(total, total, "writing files")
    result = CalibrationResult(
        spec=spec, start_distance=start_distance, best_distance=best_distance, estimates=tuple(estimates),
        final=final, agreement=agr, evaluations=len(searched), reused=reused, optimiser=type(study.sampler).__name__,
        seconds=time.perf_counter() - t0, cpu_seconds=cpu,
        population_file=spec.out, missed=missed,
    )
    files = _write_outputs(result, fitted_values)
    return replace(result, files=files)


def _sampler(spec: CalibrationSpec) -> Any:
    """CMA-ES started at the population's values (a local search from the cited/chosen priors, first steps of
    a quarter of each parameter's search range); TPE when the cmaes package is missing. Seeded either way."""
    import optuna

    x0 = {f.name: f.to_search(f.value) for f in spec.free}
    sigma0 = SIGMA0  # optuna's CMA-ES works on the search space scaled to [0, 1] per parameter
    try:
        import cmaes  # noqa: F401 - optuna's CmaEsSampler needs it
    except ImportError:
        return optuna.samplers.TPESampler(seed=spec.seed, multivariate=True,
                                          n_startup_trials=max(4, min(10, spec.evaluations // 3)))
    import warnings

    with warnings.catch_warnings():  # x0/sigma0 are deprecated since optuna 4.9 (removal in 6; pinned < 6)
        warnings.simplefilter("ignore", FutureWarning)
        return optuna.samplers.CmaEsSampler(x0=x0, sigma0=sigma0, seed=spec.seed, n_startup_trials=0,
                                            warn_independent_sampling=False)


def _missed(agr: Any) -> tuple[str, ...]:
    out = []
    for r in agr.rows:
        if r.role != "fit":
            continue
        if not math.isfinite(r.z):
            out.append(f"{r.target}: not computed from the simulation ({r.note or 'no data'})")
        elif abs(r.z) > 2:
            sim = r.simulated if isinstance(r.simulated, bool) else f"{float(r.simulated):.4g}"
            out.append(f"{r.target}: published {r.published}, simulated {sim} ({r.z:+.1f} σ)")
    return tuple(out)


def _final_run(spec: CalibrationSpec, values: dict[str, float], client: Any) -> Evaluation:
    """The fitted population at paper size, cached next to the journal (a rerun does not redo it)."""
    from studyctl.populations.free import apply_values

    pop = apply_values(spec.population, values, spec.free)
    cache = spec.out.with_name(spec.out.name + ".final.json")
    key = f"{spec.fingerprint()}:{pop.sha256}:{spec.paper_participants}"
    if cache.is_file():
        try:
            data = json.loads(cache.read_text())
            if data.get("key") == key:
                return Evaluation(values, float(data["distance"]), data["z"], pd.DataFrame(data["stats"]),
                                  float(data["seconds"]), float(data["cpu_seconds"]), spec.paper_participants)
        except (ValueError, KeyError):
            pass
    paper = replace(spec, replicates=1)
    ev = evaluate(paper, values, participants=spec.paper_participants, client=client)
    if ev.distance >= FAILED_DISTANCE:
        return ev  # a failed run is not kept: the next run of the command tries again
    _atomic_text(cache, json.dumps({"key": key, "distance": ev.distance,
                                    "z": {k: (v if math.isfinite(v) else None) for k, v in ev.z.items()},
                                    "stats": json.loads(ev.stats.to_json(orient="records")),
                                    "seconds": ev.seconds, "cpu_seconds": ev.cpu_seconds}))
    return ev


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def fitted_population(result: CalibrationResult, values: dict[str, float]) -> Any:
    """The population file's content: the fitted values, FITTED sources, a bumped version, the calibration."""
    from studyctl.populations.free import apply_values, mark_fitted

    spec = result.spec
    pop = apply_values(spec.population, values, spec.free)
    pop = mark_fitted(pop, spec.free, f"studyctl calibrate to {Path(spec.targets.path).name}")
    calibration = {
        "targets": Path(spec.targets.path).name,
        **spec.setup(),
        "sim_rate_hz": spec.sim_rate_hz,
        "evaluations": result.evaluations,
        "objective": {"start": round(result.start_distance, 4), "best": round(result.best_distance, 4)},
        # measured by this run (wall: this invocation; CPU: every simulation, journaled ones included)
        "seconds": round(result.seconds, 1), "cpu_seconds": round(result.cpu_seconds, 1),
        "estimates": {e.name: {"value": float(f"{e.estimate:.6g}"),
                               "se": None if not math.isfinite(e.se) else float(f"{e.se:.3g}"),
                               "identified": e.identified} for e in result.estimates},
        "missed": list(result.missed),
    }
    bounds = spec.population.calibration.get("bounds")
    if bounds:
        calibration["bounds"] = bounds
    return replace(pop, version=spec.population.version + 1, calibration=calibration, sha256="", path="")


FIT_HEADER = "# Fitted by studyctl calibrate "


def population_text(source: str | Path, pop: Any) -> str:
    """The fitted population's YAML: merged into the text of the file it started from when there is one, so the
    file's comments survive (:func:`~studyctl.populations.roundtrip.merge_into_text`; an earlier fit's header
    line is replaced by the new one), else dumped plainly."""
    from studyctl.populations.roundtrip import merge_into_text

    path = Path(source) if source else None
    if path is not None and path.is_file():
        lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
        merged = merge_into_text("".join(x for x in lines if not x.startswith(FIT_HEADER)), pop.to_dict())
        if merged is not None:
            return merged
    return pop.to_yaml()


def _write_outputs(result: CalibrationResult, values: dict[str, float]) -> dict[str, Path]:
    """The population file, the fit report (Markdown, HTML, CSV) and agreement.csv, each via temp + rename."""
    from studyctl.report.calibration import fit_report_html, fit_report_markdown

    spec = result.spec
    pop = fitted_population(result, values)
    stem = spec.out.with_suffix("")
    files = {
        "population": spec.out,
        "report_md": stem.with_name(stem.name + ".fit.md"),
        "report_html": stem.with_name(stem.name + ".fit.html"),
        "report_csv": stem.with_name(stem.name + ".fit.csv"),
        "agreement": stem.with_name(stem.name + ".agreement.csv"),
        "journal": spec.journal,
    }
    header = (f"{FIT_HEADER}{spec.protocol_id} --targets {Path(spec.targets.path).name} "
              f"--free {','.join(f.name for f in spec.free)} --seed {spec.seed} --participants {spec.participants}\n")
    _atomic_text(files["population"], header + population_text(spec.population.path, pop))
    frame = result.agreement.to_frame()
    est = pd.DataFrame([e.to_dict() for e in result.estimates])
    _atomic_text(files["report_csv"], pd.concat([frame.assign(kind="target"),
                                                 est.assign(kind="parameter")], ignore_index=True).to_csv(index=False))
    _atomic_text(files["agreement"], frame.to_csv(index=False))
    md = fit_report_markdown(result, pop)
    _atomic_text(files["report_md"], md)
    _atomic_text(files["report_html"], fit_report_html(result, pop))
    return files
