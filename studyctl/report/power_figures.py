"""The power-curve figure of ``studyctl power``: power against sample size, one panel per test.

Takes the power table (:data:`studyctl.power.summary.COLUMNS`) and returns a matplotlib Figure (object
API, no pyplot state). Post-hoc rows stay in the table but are not drawn (one panel per test of the plan,
one line per metric / split / compared levels, Wilson intervals as error bars).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from studyctl.report.figures import DPI
from studyctl.report.style import PALETTE

if TYPE_CHECKING:
    from matplotlib.figure import Figure

_STYLES = ("-", "--", ":", "-.")
TARGET_POWER = 0.8


def _label(row: pd.Series) -> str:
    parts = [str(row["metric"])]
    if row["split"]:
        parts.append(str(row["split"]))
    if row["kind"] in ("pairwise",) and row["groups"]:
        parts.append(str(row["groups"]))
    return " · ".join(parts)


def population_text(population: Any) -> str:
    """One line stating the effect knobs shifted on top of the population (the figure caption and the CLI)."""
    if population is None or getattr(population, "is_empty", True):
        return ("effects: none stated beyond the population's people (differences come from the simulated "
                "feedback, perception and between-person traits alone)")
    d = population.to_dict()
    bits = []
    for c, shifts in d["condition_effects"].items():
        bits += [f"{c}: {p} {v:+g}" for p, v in shifts.items()]
    for g, shifts in d["group_effects"].items():
        bits += [f"{g}: {p} {v:+g}" for p, v in shifts.items()]
    bits += [f"{p} = {v:g}" for p, v in d["baseline"].items()]
    bits += [f"SD({p}) = {v:g}" for p, v in d["between_sd"].items()]
    return "effects (shifts on top of each person's traits): " + "; ".join(bits)


def power_curve_figure(
    table: pd.DataFrame,
    *,
    title: str = "Power by sample size",
    alpha: float | None = None,
    replicates: int | None = None,
    population: Any = None,
    max_lines: int = 16,
    target: pd.DataFrame | None = None,
    target_power: float | None = None,
    note: str | None = None,
) -> Figure:
    """Power curves: one panel per test id, lines per metric/split, Wilson-interval error bars.

    Parameters
    ----------
    table
        The power table (``participants, test_id, kind, metric, split, groups, power, power_ci_low, …``).
    alpha
        The plan's significance level (drawn as a dotted line: the power of a test with no effect).
    replicates
        Replicates per sample size (in the caption).
    population
        The :class:`~studyctl.power.population.Population` (stated in the caption).
    max_lines
        Lines per panel at most (the ones with the highest power at the largest sample size).
    target, target_power
        The smallest sizes reaching the target power (:class:`studyctl.power.target.TargetTable` frame): each
        drawn as a ringed star on its curve; the target is the dashed line (0.8 without one).
    note
        A further caption line (the two-stage design's measured error beside its power figures).
    """
    from matplotlib.figure import Figure

    table = table.copy()
    for col in ("test_id", "test", "kind", "metric", "split", "groups"):  # a CSV round trip reads "" as NaN
        table[col] = table[col].fillna("").astype(str)
    drawn = table[table["kind"] != "posthoc"]
    tests = list(dict.fromkeys(drawn["test_id"]))
    n = max(len(tests), 1)
    cols = min(n, 2)
    rows = math.ceil(n / cols)
    fig = Figure(figsize=(6.0 * cols, 4.0 * rows + 0.9), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False).ravel().tolist()
    for ax in axes[n:]:
        ax.set_visible(False)
    sizes = sorted(table["participants"].unique()) if not table.empty else []
    for ax, test_id in zip(axes, tests, strict=False):
        sub = drawn[drawn["test_id"] == test_id]
        lines = list(dict.fromkeys(zip(sub["metric"], sub["split"], sub["groups"], strict=True)))
        if len(lines) > max_lines:
            last = sub[sub["participants"] == sub["participants"].max()]
            ranked = last.sort_values("power", ascending=False)
            keep = list(dict.fromkeys(zip(ranked["metric"], ranked["split"], ranked["groups"], strict=True)))
            lines = [k for k in lines if k in set(keep[:max_lines])]
        gaps = np.diff(sizes) if len(sizes) > 1 else np.array([1.0])
        dodge = 0.25 * float(gaps.min()) / max(len(lines), 1)
        for i, key in enumerate(lines):
            g = sub[(sub["metric"] == key[0]) & (sub["split"] == key[1]) & (sub["groups"] == key[2])]
            g = g.sort_values("participants")
            # a small sideways dodge keeps overlapping curves and their intervals apart
            x = g["participants"].to_numpy(dtype=float) + dodge * (i - (len(lines) - 1) / 2)
            y = g["power"].to_numpy(dtype=float)
            err = [y - g["power_ci_low"].to_numpy(dtype=float), g["power_ci_high"].to_numpy(dtype=float) - y]
            ax.errorbar(
                x,
                y,
                yerr=err,
                color=PALETTE[i % len(PALETTE)],
                linestyle=_STYLES[(i // len(PALETTE)) % 4],
                marker="o",
                markersize=3.5,
                capsize=2.5,
                linewidth=1.4,
                label=_label(g.iloc[0]),
            )
            hit = _target_size(target, test_id, key)
            if hit is not None:
                at = np.flatnonzero(g["participants"].to_numpy() == hit)
                if at.size:
                    ax.plot(x[at], y[at], marker="*", markersize=13, markerfacecolor="none",
                            markeredgecolor=PALETTE[i % len(PALETTE)], markeredgewidth=1.4, linestyle="none")
                    ax.annotate(f"n={hit}", (x[at][0], y[at][0]), textcoords="offset points", xytext=(4, -11),
                                fontsize=7, color=PALETTE[i % len(PALETTE)])
        ax.axhline(TARGET_POWER if target_power is None else target_power, color="0.45", linestyle="--", linewidth=0.9)
        if alpha is not None:
            ax.axhline(alpha, color="0.6", linestyle=":", linewidth=0.9)
        first = sub.iloc[0]
        ax.set_title(f"{test_id} ({first['test']})", fontsize=10, loc="left")
        ax.set_xlabel("participants")
        ax.set_ylabel("power (fraction significant)")
        ax.set_ylim(-0.02, 1.02)
        if sizes:
            ax.set_xticks(sizes)
        ax.grid(alpha=0.25)
        if len(lines) > 6:  # many curves: the legend goes beside the panel, not over it
            ax.legend(fontsize=6.5, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
        else:
            ax.legend(fontsize=7, loc="best", frameon=False)
    caption = [f"{title}"]
    detail = []
    if replicates is not None:
        detail.append(f"{replicates} simulated studies per sample size")
    goal = TARGET_POWER if target_power is None else target_power
    if alpha is not None:
        detail.append(f"alpha = {alpha:g} (dotted); {goal:g} dashed; bars: 95% Wilson intervals")
    if target is not None:
        detail.append(f"star: smallest size reaching power {goal:g}")
    fig.suptitle(caption[0], fontsize=11)
    fig.supxlabel("; ".join(detail) + ("\n" + note if note else "") + "\n" + population_text(population), fontsize=8)
    return fig


def _target_size(target: pd.DataFrame | None, test_id: str, key: tuple[str, str, str]) -> int | None:
    """The smallest size reaching the target for one curve (metric, split, groups), or None."""
    if target is None or target.empty:
        return None
    t = target.copy()
    for col in ("test_id", "metric", "split", "groups"):
        t[col] = t[col].fillna("").astype(str)
    m = t[(t["test_id"] == test_id) & (t["metric"] == key[0]) & (t["split"] == key[1]) & (t["groups"] == key[2])]
    m = m[m["participants"].notna()]
    return None if m.empty else int(m["participants"].iloc[0])


def write_png(fig: Figure, path: str | Path) -> Path:
    """Save ``fig`` as a PNG file (``dpi`` as the report's figures)."""
    fig.savefig(path, format="png", dpi=DPI)
    return Path(path)
