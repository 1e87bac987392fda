"""How the virtual needle operator answers the questionnaires (seed 001, Table 2 and Figure A1).

A Likert code is judged from the session's completed trials (faster, fewer scans, fewer timeouts than in the
first, baseline scenario), never from anything the operator could not have noticed itself.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np


def judge_item(item: Mapping[str, Any], trials: Iterable[Mapping[str, Any]], rng: np.random.Generator) -> int:
    """A Likert code for ``item`` from ``trials`` (condition, its view, duration, scans, how each ended, in
    plan order), with response noise from ``rng``."""
    codes = list(item.get("codes") or [1, 2, 3, 4, 5])
    lo, hi = min(codes), max(codes)
    mid = (lo + hi) / 2.0
    half = (hi - lo) / 2.0
    rows = [dict(r) for r in trials]
    cond = item.get("condition")
    key = f"{item.get('id', '')} {item.get('text', '')}".lower()
    mine = [r for r in rows if r.get("condition") == cond] if cond else []
    first = rows[0].get("condition") if rows else None
    base = [r for r in rows if r.get("condition") == first]

    def mean(sel: list[dict[str, Any]], k: str) -> float:
        vals = [float(r[k]) for r in sel if r.get(k) is not None]
        return sum(vals) / len(vals) if vals else math.nan

    def faster(sel: list[dict[str, Any]]) -> float:
        d0, d1 = mean(base, "duration_s"), mean(sel, "duration_s")
        return (d0 - d1) / d0 if sel and base and d0 > 0 else 0.0

    def fewer_scans(sel: list[dict[str, Any]]) -> float:
        s0, s1 = mean(base, "scans"), mean(sel, "scans")
        return (s0 - s1) / s0 if sel and base and s0 > 0 else 0.0

    def gain(sel: list[dict[str, Any]]) -> float:
        """Relative improvement over the first scenario (time counts twice as much as scans)."""
        if not sel or not base:
            return 0.0
        if mean(base, "scans") > 0:
            return (2 * faster(sel) + fewer_scans(sel)) / 3
        return faster(sel)

    def timeouts(sel: list[dict[str, Any]]) -> float:
        """Share of trials stopped by the time limit (the target not reached in time)."""
        late = sum(1 for r in sel if r.get("timed_out") or r.get("ended_by") == "time_limit")
        return late / len(sel) if sel else 0.0

    # the scenarios with enhanced haptics: after the first (baseline) one, without the real-time image
    haptic = [r for r in rows if r.get("visual") != "realtime" and r.get("condition") != first]
    if "baseline" in key or "improv" in key:
        score = mid + half * math.tanh(3.0 * gain(mine))
    elif "navigat" in key or "easy" in key and "haptic" not in key:
        score = mid + half * math.tanh(3.0 * faster(mine) - 1.5 * timeouts(mine))
    elif "confiden" in key:
        score = mid + half * math.tanh(1.5 * gain(mine) + 1.5 * fewer_scans(mine) - 1.5 * timeouts(mine))
    elif "equal" in key:
        rt = [r for r in rows if r.get("visual") == "realtime"]
        score = hi - 4 * half * abs(gain(rt) - gain(haptic)) if rt and haptic else mid
    elif "haptic" in key or "easier" in key:
        score = mid + half * math.tanh(3.0 * gain(haptic))
    elif "learn" in key:
        half_n = len(rows) // 2
        early, late = rows[:half_n], rows[half_n:]
        d0, d1 = mean(early, "duration_s"), mean(late, "duration_s")
        score = mid + half * (math.tanh(3.0 * (d0 - d1) / d0) if early and late and d0 > 0 else 0.0)
    else:
        score = mid
    score += float(rng.normal(0.0, 0.6))
    return int(min(hi, max(lo, round(score))))
