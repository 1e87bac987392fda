"""The one line that says at which loop rate each condition's simulated sessions ran, and whether a cap set it.

Printed by ``studyctl power`` before a run and written under its power curve when a cap slowed a loop; kept here so
that every command that reports simulated loop rates says it in the same words.
"""

from __future__ import annotations

from collections.abc import Mapping


def loop_rates_line(rates: Mapping[str, float], cap: float | None, undo: str = "--full-rate") -> str:
    """``rates``: condition → loop rate (Hz) as run; ``cap``: the ``--sim-rate-hz`` cap, None at the protocol's
    rates; ``undo``: how the command runs the protocol's rates instead (``studyctl simulate`` has no --full-rate).
    Conditions that share a rate are listed together, in ``rates``' order."""
    by_rate: dict[float, list[str]] = {}
    for cond, rate in rates.items():
        by_rate.setdefault(rate, []).append(cond)
    listed = "; ".join(f"{', '.join(conds)} {rate:g} Hz" for rate, conds in by_rate.items()) or "no feedback loop"
    how = (f"rate-adjustable loops capped at {cap:g} Hz; {undo} for the protocol's rates" if cap is not None
           else "the protocol's rates")
    return f"loop rates: {listed} ({how})"
