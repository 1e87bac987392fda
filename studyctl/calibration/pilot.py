"""Targets from a pilot study's database (``studyctl calibrate --pilot-db``) instead of a paper."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from studyctl.errors import NotFoundError, PopulationError
from studyctl.populations.targets import Target, TargetSet, load_targets_file


def _url(db: str) -> str:
    return db if "://" in db else f"sqlite:///{Path(db).resolve()}"


def pilot_targets(db: str, plan: Any, protocol: Any, *, template: str | Path | None = None) -> TargetSet:
    """The pilot's own numbers as targets.

    With ``template`` (a targets file): the same targets, each value replaced by the pilot's (uncertainty: its
    bootstrap SE over the pilot's participants), roles kept. Without: every trial metric's mean per condition
    (role fit) and between-participant SD per condition (role validation).
    """
    from studyctl.analysis import compute_metrics, run_plan
    from studyctl.calibration.simulated import simulated_values
    from studyctl.store.workspace import open_study

    if "://" not in db and not Path(db).is_file():
        raise NotFoundError(f"--pilot-db {db!r}: no such database file (give the pilot's study.db or a URL)")
    with open_study(_url(db), None, None) as opened:
        ran = opened.study.protocol_name
        if ran and ran != protocol.study.id:
            raise PopulationError(f"--pilot-db {db}: the pilot ran protocol {ran!r}, not {protocol.study.id!r}; "
                                  f"calibrate {ran} with it, or give the pilot of {protocol.study.id}")
        table = compute_metrics(plan, opened.store, opened.study)
        seed = int(opened.study.seed or 0)
    tests = run_plan(plan, table).to_frame()
    if template is not None:
        base = load_targets_file(template, plan=plan, protocol=protocol)
        targets = list(base.targets)
    else:
        targets = []
        for mid in plan.metrics:
            if plan.metric_name(mid) == "likert":
                continue
            for c in protocol.condition_ids:
                targets.append(Target(f"{mid}_{c}_mean", mid, "mean", 0.0, "fit", {"condition": c}))
                targets.append(Target(f"{mid}_{c}_sd", mid, "sd", 0.0, "validation", {"condition": c}))
        base = None
    sim = simulated_values(targets, table.frame, tests, alpha=base.alpha if base else plan.alpha,
                           rng=np.random.default_rng(seed))
    out = []
    for t, v in zip(targets, sim.values, strict=True):
        if isinstance(v.value, float) and not np.isfinite(v.value):
            continue  # the pilot has no data for it
        unc = {} if t.is_test else {"se": float(v.se) if np.isfinite(v.se) else abs(float(v.value)) * 0.1,
                                    "n": max(v.participants, 1), "basis": "pilot"}
        out.append(replace(t, value=v.value, uncertainty=unc, note=f"pilot {db}", location=f"{db} (pilot)"))
    return TargetSet(protocol=protocol.study.id, source=f"pilot study {db}", targets=tuple(out),
                     alpha=base.alpha if base else float(plan.alpha), plan=plan.study, path=str(db),
                     sha256=_digest(out))


def _digest(targets: list[Target]) -> str:
    """A stable digest of the pilot's targets (part of the calibration journal's fingerprint; Python's hash()
    of strings differs per process, which made every rerun start a new journal study)."""
    data = [[t.id, t.role, t.statistic, repr(t.value), sorted((k, repr(v)) for k, v in t.uncertainty.items())]
            for t in targets]
    return hashlib.sha256(json.dumps(data).encode()).hexdigest()
