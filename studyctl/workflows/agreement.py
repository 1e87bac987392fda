"""The "simulated vs published" comparison of a study's report: a simulated study (every session run by a
virtual participant) is compared with the published targets shipped for its protocol."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from studyctl.analysis.results import AnalysisResult
from studyctl.store.reader import StudyReader


def with_agreement(result: AnalysisResult, reader: StudyReader, *, targets: str | Path | None = None
                   ) -> AnalysisResult:
    """``result`` with the comparison's tables (``agreement_info``, and ``agreement`` when targets exist) for a
    simulated study; unchanged for a study of people."""
    compared = simulated_vs_published(result, reader, targets=targets)
    if compared is None:
        return result
    frame, info = compared
    extra = {"agreement_info": info} | ({} if frame is None else {"agreement": frame})
    return replace(result, tables={**result.tables, **extra})


def simulated_vs_published(result: AnalysisResult, reader: StudyReader, *, targets: str | Path | None = None
                           ) -> tuple[pd.DataFrame | None, pd.DataFrame] | None:
    """(agreement table, info lines) for a simulated study, or None for a study of people.

    ``reader``: the study's open :class:`~studyctl.store.reader.StudyReader` (the one its analysis read).
    ``targets``: a targets file (default: ``studyctl/populations/<protocol>.targets.yaml`` when shipped).
    """
    plan = result.plan
    from studyctl.calibration import agreement, simulated_values
    from studyctl.populations.targets import load_targets_file, shipped_targets_path

    events = reader.session_events(("session_plan", "population"))
    seed = reader.study.seed
    plans = [e.payload for e in events if e.kind == "session_plan"]
    pops = [dict(e.payload) for e in events if e.kind == "population" and e.payload]
    sessions, virtual = len(plans), sum(bool((p or {}).get("virtual")) for p in plans)
    if not sessions or virtual < sessions:
        return None
    used = Counter(f"{p.get('name')} v{p.get('version')} (sha256 {str(p.get('sha256'))[:12]})" for p in pops)
    info = [("sessions", f"{sessions}, all run by virtual participants")]
    info.append(("population", "; ".join(f"{k}: {n} session(s)" for k, n in used.items()) if used else
                 "none (the participant's default parameters; no population file)"))
    path = Path(targets) if targets is not None else shipped_targets_path(plan.study)
    frame = None
    if path is None:
        info.append(("targets", f"none shipped for {plan.study} (studyctl/populations/{plan.study}.targets.yaml)"))
    else:
        tset = load_targets_file(path, plan=plan)
        info.append(("targets", f"{path.name}: {tset.source} ({len(tset.by_role('fit'))} fit, "
                                f"{len(tset.by_role('validation'))} validation)"))
        sim = simulated_values(tset.targets, result.data.frame, result.to_frame(), alpha=tset.alpha,
                               rng=np.random.default_rng(seed))
        frame = agreement(tset.targets, sim, tset.alpha).to_frame()
    return frame, pd.DataFrame(info, columns=["item", "value"])
