"""Formatting of the simulated-vs-published comparison and of ``studyctl calibrate``'s fit report."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import pandas as pd

from studyctl.populations.targets import SPREADS
from studyctl.report.style import fmt_num

Block = tuple


def _yn(v: Any) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    return "yes" if bool(v) else "NO"


def _val(v: Any) -> str:
    if isinstance(v, bool):
        return "significant" if v else "not significant"
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "NOT COMPUTED"
    return fmt_num(float(v))


def _band(lo: Any, hi: Any) -> str:
    try:
        lo, hi = float(lo), float(hi)
    except (TypeError, ValueError):
        return ""
    return "" if math.isnan(lo) or math.isnan(hi) else f"[{fmt_num(lo)}, {fmt_num(hi)}]"


def _chance(v: Any) -> str:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return ""
    return "" if math.isnan(v) else f"{v:.0%}"


def _frac(x: Any, n: Any) -> str:
    return "–" if x is None or not n else f"{x:.0%} ({round(x * n)}/{n})"


def summary_rows(summary: dict[str, dict[str, Any]]) -> tuple[list[str], list[list[str]]]:
    head = ["targets", "n", "direction right", "verdict reproduced", "within published band", "SD within 1.5×",
            "agree on every check"]
    body = []
    for role in ("fit", "validation", "all"):
        s = summary.get(role) or {}
        if not s.get("targets"):
            continue
        body.append([role, str(s["targets"]), _frac(s["direction_fraction"], s["direction_n"]),
                     _frac(s["verdict_fraction"], s["verdict_n"]), _frac(s["within_fraction"], s["within_n"]),
                     _frac(s["sd_ratio_within_fraction"], s["sd_ratio_n"]), _frac(s["agree_fraction"], s["agree_n"])])
    return head, body


def chance_line(summary: dict[str, dict[str, Any]]) -> str | None:
    """What chance alone allows: of the verdicts with a published p and of the values whose band is the paper's
    sampling interval, how many the simulation reproduced and how many a same-size replication of the paper itself
    would reproduce on average."""
    s = summary.get("all") or {}
    parts = []
    n = s.get("verdict_p_n") or 0
    if n:
        parts.append(f"of the {n} verdict{'s' if n != 1 else ''} whose p the paper prints, the simulated study "
                     f"reproduced {s['verdict_p_reproduced']} where a replication of the paper with as many people "
                     f"would reproduce {s['verdict_expected']:.1f} on average")
    m = s.get("within_p_n") or 0
    if m:
        parts.append(f"of the {m} value{'s' if m != 1 else ''} whose band is the paper's own sampling interval, "
                     f"{s['within_p_reproduced']} lie in it where such a replication would place "
                     f"{s['within_expected']:.1f}")
    if not parts:
        return None
    return ("What chance alone allows (column \"replication\": how often a same-size replication of the paper "
            "passes that check, the published value taken as uncertain as the paper says, Cumming 2008): "
            + "; ".join(parts) + ". A verdict near the 0.05 level is missed about half the time, and a value "
            "leaves a ±1.96 SE band about one time in six, even by a population that is exactly the paper's.")


# Statistics reported in the metric's own unit (a proportion, a % change, a p-value or a verdict has none).
_IN_UNIT = ("mean", "sd", "median", "iqr")


def agreement_table(frame: pd.DataFrame, units: Mapping[str, str] | None = None) -> tuple[list[str], list[list[str]]]:
    """One row per target; ``units`` (plan metric id -> unit) labels the metric of values in that unit.

    Ten columns, the checks last: a value and its interval share a cell, and metric, place and statistic share one,
    so that the whole row fits a report's width (with fourteen, the checks were scrolled out of sight).
    ``agreement.csv`` keeps every field in its own column."""
    head = ["target", "role", "compared", "published (band)", "simulated (95% interval)", "same direction",
            "within band", "same verdict", "replication", "agrees"]
    body = []
    for r in frame.to_dict("records"):
        within = _yn(r["within"])
        if r["statistic"] in SPREADS and r["within"] is not None and not (isinstance(r["sd_ratio"], float)
                                                                      and math.isnan(r["sd_ratio"])):
            within = f"{within} (ratio {r['sd_ratio']:.2f})"
        simulated = _val(r["simulated"])
        note = r.get("note")
        if r["statistic"] == "verdict" and isinstance(note, str) and note and not note.startswith(
                ("no ", "test status")):
            simulated = f"{simulated} ({note})"
        unit = (units or {}).get(r["metric"], "") if r["statistic"] in _IN_UNIT else ""
        metric = f"{r['metric']} ({unit})" if unit else r["metric"]
        published = " ".join(x for x in (_val(r["published"]), _band(r["published_low"], r["published_high"])) if x)
        if r["band"]:  # what the band is; a verdict's says what is checked ("verdict and direction (a > b)")
            published += f"{';' if r['statistic'] == 'verdict' else ''} {r['band']}"
        simulated = " ".join(x for x in (simulated, _band(r["simulated_low"], r["simulated_high"])) if x)
        body.append([r["target"], r["role"], f"{metric}, {r['where'] or 'all'}: {r['statistic']}", published,
                     simulated, _yn(r["same_direction"]), within, _yn(r["same_verdict"]),
                     _chance(r.get("replication")), _yn(r["agrees"])])
    return head, body


def agreement_blocks(frame: pd.DataFrame | None, info: pd.DataFrame | None, level: int = 2,
                     units: Mapping[str, str] | None = None) -> list[Block]:
    """The "Simulated vs published" section: which population and targets, the fractions, every target
    (``units``: plan metric id -> unit, shown beside the metric of means, SDs, medians and IQRs)."""
    out: list[Block] = [("h", level, "Simulated vs published")]
    lines = [] if info is None else [f"{k}: {v}" for k, v in zip(info["item"], info["value"], strict=True)
                                     if k != "summary"]
    if lines:
        out.append(("list", lines))
    if frame is None or frame.empty:
        out.append(("p", "No published targets to compare with."))
        return out
    from studyctl.calibration.agreement import summary_from_frame

    summary = summary_from_frame(frame)
    out.append(("table", *summary_rows(summary)))
    chance = chance_line(summary)
    if chance:
        out.append(("p", chance))
    out.append(("p", "Each band says what it is: the paper's 95 % CI as printed; a Wilson or exact Poisson 95 % "
                "interval recomputed from the paper's counts; ±1.96 SE or ±1 SD as published, recomputed from the "
                "paper, or CHOSEN; a CHOSEN band is a tolerance picked by hand (the targets file's note says why), "
                "not a confidence interval. An SD or CV agrees when simulated/published lies within 1/1.5 … 1.5. "
                "Fit targets were used to calibrate the population; validation targets never were."))
    out.append(("table", *agreement_table(frame, units)))
    return out


def _fit_blocks(result: Any, pop: Any) -> list[Block]:
    spec = result.spec
    from pathlib import Path

    out: list[Block] = [("h", 1, f"Calibration of {pop.name} v{pop.version} to {Path(spec.targets.path).name}")]
    out.append(("list", [
        f"protocol: {spec.protocol_id}; participant: {pop.participant}; started from {spec.population.label}",
        f"targets: {spec.targets.path} ({len(spec.targets.by_role('fit'))} fit, "
        f"{len(spec.targets.by_role('validation'))} validation); source: {spec.targets.source}",
        f"free parameters: {', '.join(f.name for f in spec.free)}",
        f"fit: {result.evaluations} candidate populations, each {spec.replicates} simulated "
        f"stud{'y' if spec.replicates == 1 else 'ies'} × {spec.participants} people with the same seeds (seed "
        f"{spec.seed}: common random numbers); optimiser: Optuna {result.optimiser}; {result.reused} evaluation(s) "
        "taken from the journal of an earlier run",
        f"distance over the fit targets (Σ z²): start {result.start_distance:.3g}, best {result.best_distance:.3g}",
        f"the fitted population was then run once at the paper's size ({spec.paper_participants} people) for the "
        "table below",
        f"time: {result.seconds:.0f} s wall for this run; {result.cpu_seconds:.0f} s CPU in the simulations of "
        "all evaluations (journaled ones included) and the paper-size run",
        f"written: {result.population_file} (sha256 {pop.sha256[:12]})",
    ]))
    if result.missed:
        out.append(("alert", f"The calibration did not reach {len(result.missed)} fit target(s) (more than 2 σ "
                    "away at the paper's size):"))
        out.append(("list", list(result.missed)))
    flat = [e for e in result.estimates if not e.identified]
    if flat:
        out.append(("alert", "Not identified by these targets (moving the parameter by ±15 % of its range changes "
                    "the distance by less than 1): " + ", ".join(f"{e.name} (rise {e.profile_rise:.2g})"
                                                               for e in flat)))
    lower = [e for e in result.estimates if e.profile_rise < 0]
    if lower:
        out.append(("alert", "The search had not converged: a ±15 % step of " + ", ".join(
            f"{e.name} (by {-e.profile_rise:.2g})" for e in lower) + " lowered the distance below the best "
            "candidate's; run again with more --evaluations (the journal keeps what is done)"))
    out.append(("h", 2, "Parameter estimates"))
    head = ["parameter", "start", "estimate", "SE (curvature)", "search range", "scale", "profile rise at ±h",
            "identified"]
    body = [[e.name, fmt_num(e.start), fmt_num(e.estimate), fmt_num(e.se) if math.isfinite(e.se) else "∞ (flat)",
             f"[{fmt_num(e.low)}, {fmt_num(e.high)}]", e.scale, f"{e.profile_rise:.3g}", _yn(e.identified)]
            for e in result.estimates]
    out.append(("table", head, body))
    out.append(("p", "SE from the curvature of the distance along each parameter (others at their estimate); "
                "the distance is a χ²-like sum, so SE = √(2 / second derivative)."))
    out.extend(agreement_blocks(result.agreement.to_frame(), None,
                                units={m: spec.plan.metric_unit(m) for m in spec.plan.metrics}))
    return out


def fit_report_markdown(result: Any, pop: Any) -> str:
    from studyctl.report.document import render_markdown

    return render_markdown(_fit_blocks(result, pop))


def fit_report_html(result: Any, pop: Any) -> str:
    from studyctl.report.document import render_html

    return render_html(f"Calibration of {pop.name}", _fit_blocks(result, pop))


def calibration_json(result: Any, pop_sha256: str = "") -> dict[str, Any]:
    """``studyctl calibrate --json``: settings, estimates with SEs, the agreement per target and per role (fit and
    validation apart), what was missed, the measured time and the files (NaN → null)."""
    from pathlib import Path

    spec = result.spec
    frame = result.agreement.to_frame()
    rows = frame.astype(object).where(frame.notna(), None).to_dict(orient="records")
    return {
        "format": "studyctl-calibration/1",
        "protocol": spec.protocol_id,
        "started_from": spec.population.label,
        "targets": str(spec.targets.path),
        "targets_source": spec.targets.source,
        **spec.setup(),
        "paper_participants": spec.paper_participants,
        "optimiser": result.optimiser,
        "evaluations": result.evaluations,
        "reused": result.reused,
        "distance": {"start": result.start_distance, "best": result.best_distance},
        "seconds": result.seconds,
        "cpu_seconds": result.cpu_seconds,
        "estimates": [e.to_dict() for e in result.estimates],
        "converged": not any(e.profile_rise < 0 for e in result.estimates),
        "summary": result.agreement.summary(),
        "agreement": rows,
        "missed": list(result.missed),
        "population": {"file": str(result.population_file), "sha256": pop_sha256,
                       "name": Path(result.population_file).name},
        "files": {k: str(v) for k, v in result.files.items()},
    }
