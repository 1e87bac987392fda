"""Figures that mirror the papers' results sections, drawn with matplotlib's object API (no pyplot state).

Every function takes tidy tables (from :class:`~studyctl.analysis.results.AnalysisResult`) and returns a
:class:`matplotlib.figure.Figure`; :func:`figure_bytes` renders one for print (PNG at 300 dpi, SVG, PDF),
with panel letters on figures of more than one panel. matplotlib is imported inside the functions so that
``import studyctl`` never pays for it.
"""

from __future__ import annotations

import contextlib
import io
import math
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from studyctl.errors import ConfigError
from studyctl.report.apa import p_text
from studyctl.report.style import PALETTE, stars

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

DPI = 300  # print resolution of the PNGs
FORMATS = ("png", "svg", "pdf")
_PANEL = "studyctl-panel"  # gid of the axes that are panels (twin axes and legends are not)


def _figure(
    n_panels: int, *, panel_w: float = 4.2, panel_h: float = 3.4, cols: int | None = None
) -> tuple[Figure, list[Axes]]:
    from matplotlib.figure import Figure

    cols = cols or min(n_panels, 2 if n_panels == 4 else 3)
    rows = math.ceil(n_panels / cols)
    fig = Figure(figsize=(panel_w * cols, panel_h * rows + 0.6), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False).ravel().tolist()
    for ax in axes[n_panels:]:
        ax.set_visible(False)
    for ax in axes[:n_panels]:
        ax.set_gid(_PANEL)
    return fig, axes[:n_panels]


def _panel_letters(fig: Figure) -> None:
    """Bold A, B, C … at the top left of each panel when a figure has more than one (journals' convention)."""
    panels = [ax for ax in fig.axes if ax.get_gid() == _PANEL and ax.get_visible() and ax.axison]
    if len(panels) < 2 or getattr(fig, "_studyctl_lettered", False):
        return
    for i, ax in enumerate(panels):
        ax.text(-0.02, 1.02, chr(ord("A") + i), transform=ax.transAxes, ha="right", va="bottom", fontsize=12,
                fontweight="bold")
    fig._studyctl_lettered = True


def _wrap_title(fig: Figure) -> None:
    """Break a suptitle wider than its figure over lines (about 10 characters per inch at 11 pt)."""
    import textwrap

    title = fig.get_suptitle()
    width = int(fig.get_figwidth() * 10)
    if title and len(title) > width:
        fig.suptitle("\n".join(textwrap.wrap(title, width)), fontsize=11)


def figure_bytes(fig: Figure, fmt: str = "png") -> bytes:
    """The figure as ``fmt`` bytes: PNG at :data:`DPI`, or vector SVG / PDF (fonts as text in SVG)."""
    if fmt not in FORMATS:
        raise ConfigError(f"figure format {fmt!r} is not one of {', '.join(FORMATS)}")
    _wrap_title(fig)
    _panel_letters(fig)
    buf = io.BytesIO()
    # Fixed metadata: the same figure gives the same bytes (no creation date in SVG/PDF), and a fixed salt for the
    # SVG element ids, which matplotlib otherwise salts with a random uuid per save.
    meta = {"png": {"Software": None}, "svg": {"Date": None}, "pdf": {"CreationDate": None}}[fmt]
    import matplotlib

    with matplotlib.rc_context({"svg.hashsalt": "studyctl"}), _laid_out_for(fig, fmt):
        fig.savefig(buf, format=fmt, dpi=DPI, metadata=meta)
    return buf.getvalue()


@contextlib.contextmanager
def _laid_out_for(fig: Figure, fmt: str) -> Iterator[None]:
    """Run the figure's layout engine once, as ``savefig(format=fmt, dpi=DPI)`` would, then hold it off.

    Why: with a layout engine, ``savefig`` draws the whole figure twice, once with rendering disabled only to run
    the layout, once for real; running the engine alone skips that first pass (about a fifth of a save; the
    report saves each figure three times). The engine runs under the same conditions as in ``savefig`` (the
    format's own canvas and renderer, the figure at DPI), so the positions, and the bytes, are those ``savefig``
    gives. Each format still gets its own layout: text measured by the SVG/PDF renderers lays a figure out a
    little differently (up to ~0.001 of the figure) from Agg's at 300 dpi, so one layout for all three formats
    would change the SVG and PDF.
    """
    engine = fig.get_layout_engine()
    if engine is None or not fig.axes:
        yield
        return
    import matplotlib
    from matplotlib.backend_bases import get_registered_canvas_class

    canvas, dpi = fig.canvas, fig.dpi
    try:
        get_registered_canvas_class(fmt)(fig)  # the canvas savefig switches to (it attaches itself to fig)
        fig.dpi = DPI
        with contextlib.suppress(ValueError):  # as Figure.draw does
            engine.execute(fig)
    finally:
        fig.dpi = dpi
        fig.set_canvas(canvas)
    # No engine at all (not "none", a placeholder engine that savefig would still draw the figure for).
    with matplotlib.rc_context({"figure.autolayout": False, "figure.constrained_layout.use": False}):
        fig.set_layout_engine(None)
    try:
        yield
    finally:
        fig.set_layout_engine(engine)


def png_bytes(fig: Figure) -> bytes:
    """The figure as PNG bytes (300 dpi)."""
    return figure_bytes(fig, "png")


def _spread(n: int, width: float) -> np.ndarray:
    """Deterministic horizontal offsets for n points (golden-ratio sequence: scattered, yet the same figure
    every run, no random generator involved)."""
    if n <= 1:
        return np.zeros(n)
    return ((np.arange(n) * 0.6180339887) % 1.0 - 0.5) * width


def _wrap(label: str, width: int = 11) -> str:
    """Break a tick label over lines so neighbouring labels never collide."""
    import textwrap

    return "\n".join(textwrap.wrap(label, width)) or label


def _ylabel(label: str, unit: str) -> str:
    return f"{label} ({unit})" if unit else label


def box_panel(
    ax: Axes,
    units: pd.DataFrame,
    *,
    conditions: Sequence[tuple[str, str]],
    groups: Sequence[tuple[str, str]] | None,
    label: str,
    unit: str,
    marks: pd.DataFrame | None = None,
) -> None:
    """Box plots of one metric per condition (side by side per group when ``groups``), points overlaid.

    ``marks`` are rows of the tests table for this metric: significant pairwise/post-hoc rows between
    conditions become brackets with stars; significant two-sample rows between groups within a condition
    become a star above that condition; the omnibus p goes into the panel title.
    """
    cond_ids = [c for c, _ in conditions]
    groups = list(groups or [])
    n_g = max(len(groups), 1)
    width = 0.7 / n_g
    top = -np.inf
    bottom = np.inf
    for gi, (gid, glabel) in enumerate(groups or [(None, None)]):
        data, pos = [], []
        for ci, cid in enumerate(cond_ids):
            sel = units[units["condition"] == cid]
            if gid is not None:
                sel = sel[sel["group"] == gid]
            vals = sel["value"].to_numpy(dtype=float)
            vals = vals[np.isfinite(vals)]
            data.append(vals)
            pos.append(ci + (gi - (n_g - 1) / 2) * width)
            if len(vals):
                top, bottom = max(top, vals.max()), min(bottom, vals.min())
        color = PALETTE[gi % len(PALETTE)]
        nonempty = [(d, p) for d, p in zip(data, pos, strict=True) if len(d)]
        if nonempty:
            bp = ax.boxplot(
                [d for d, _ in nonempty],
                positions=[p for _, p in nonempty],
                widths=width * 0.8,
                patch_artist=True,
                showfliers=False,
                manage_ticks=False,
                medianprops={"color": "black", "linewidth": 1.4},
            )
            for patch in bp["boxes"]:
                patch.set_facecolor(color)
                patch.set_alpha(0.35)
                patch.set_edgecolor(color)
            for d, p in nonempty:
                ax.scatter(
                    p + _spread(len(d), width * 0.5), np.sort(d), s=10, color=color, alpha=0.85, zorder=3, linewidths=0
                )
        if gid is not None:
            ax.scatter(
                [], [], color=color, label=f"{glabel} (n={units.loc[units['group'] == gid, 'participant'].nunique()})"
            )
    ax.set_xticks(range(len(cond_ids)), [_wrap(lbl) for _, lbl in conditions], fontsize=8)
    ax.set_xlim(-0.6, len(cond_ids) - 0.4)
    ax.set_ylabel(_ylabel(label, unit))
    ax.grid(axis="y", alpha=0.3)
    if groups:
        ax.legend(fontsize=8, frameon=False, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncols=len(groups))
    if not np.isfinite(top):
        ax.text(0.5, 0.5, "no values", transform=ax.transAxes, ha="center", va="center", color="gray")
        return
    span = (top - bottom) or max(abs(top), 1.0)
    title = label
    if marks is not None and not marks.empty:
        omni = marks[marks["kind"] == "omnibus"]
        if omni.empty:  # a single two-level comparison of conditions (e.g. manual vs haptic) heads the panel
            omni = marks[(marks["kind"] == "two_sample") & (marks["compare"] == "condition")]
        if len(omni) == 1 and np.isfinite(omni["p"].iloc[0]):
            r = omni.iloc[0]
            title += f"\n{_test_name(r['test'])}, {p_text(r['p'])}"
        level = top + 0.06 * span
        pairs = marks[marks["kind"].isin(["posthoc", "pairwise", "two_sample"]) & (marks["compare"] == "condition")]
        span_of = {i: _bracket_span(str(g), cond_ids) for i, g in zip(pairs.index, pairs["groups"], strict=True)}
        pairs = pairs.loc[sorted(pairs.index, key=lambda i: span_of[i])]
        for _, r in pairs.iterrows():
            p = r["p_adj"] if np.isfinite(r["p_adj"]) else r["p"]
            sig = r["significant"] if r["significant"] is not None else (np.isfinite(p) and p < r["alpha"])
            if not sig or " vs " not in str(r["groups"]):
                continue
            a, b = str(r["groups"]).split(" vs ", 1)
            if a not in cond_ids or b not in cond_ids:
                continue
            x1, x2 = sorted((cond_ids.index(a), cond_ids.index(b)))
            mark = stars(p) if np.isfinite(p) else "*"
            ax.plot(
                [x1, x1, x2, x2], [level, level + 0.02 * span, level + 0.02 * span, level], color="black", linewidth=0.9
            )
            ax.text((x1 + x2) / 2, level + 0.025 * span, mark or "*", ha="center", va="bottom", fontsize=9)
            level += 0.09 * span
        groupwise = marks[(marks["compare"] == "group") & marks["kind"].isin(["two_sample"])]
        for _, r in groupwise.iterrows():
            split = str(r["split"])
            if not split.startswith("condition="):
                continue
            cid = split.split("=", 1)[1]
            p = r["p_adj"] if np.isfinite(r["p_adj"]) else r["p"]
            if cid in cond_ids and r["significant"]:
                ax.text(cond_ids.index(cid), top + 0.03 * span, stars(p) or "*", ha="center", fontsize=10)
        ax.set_ylim(top=max(level, top + 0.1 * span) + 0.05 * span)
    ax.set_title(title, fontsize=10)


def _bracket_span(groups: str, cond_ids: list[str]) -> int:
    a, _, b = groups.partition(" vs ")
    if a in cond_ids and b in cond_ids:
        return abs(cond_ids.index(a) - cond_ids.index(b))
    return 99


_TEST_NAMES = {
    "kruskal_wallis": "Kruskal-Wallis",
    "anova_oneway": "ANOVA",
    "friedman": "Friedman",
    "rm_anova": "RM-ANOVA",
    "rank_sum": "rank-sum",
    "signed_rank": "signed-rank",
}


def _test_name(test: str) -> str:
    return _TEST_NAMES.get(test, test)


def box_figure(panels: list[dict[str, Any]], *, title: str) -> Figure:
    """One box-plot panel per metric; each panel dict holds the keyword arguments of :func:`box_panel`."""
    fig, axes = _figure(len(panels))
    for ax, panel in zip(axes, panels, strict=True):
        box_panel(ax, **panel)
    fig.suptitle(title, fontsize=11)
    return fig


def proportion_figure(
    props: pd.DataFrame,
    *,
    conditions: Sequence[tuple[str, str]],
    levels: Sequence[str] | None,
    label: str,
    title: str,
) -> Figure:
    """Pooled proportions with their Wilson intervals: bars per condition (grouped by level when given).

    ``props`` columns: condition, level, successes, chances, estimate, ci_low, ci_high.
    """
    fig, (ax,) = _figure(1, panel_w=max(5.0, 1.3 * len(conditions) * max(1, len(levels or [])) ** 0.5 + 2), panel_h=3.8)
    cond_ids = [c for c, _ in conditions]
    series = list(levels) if levels else [None]
    width = 0.8 / len(series)
    for li, lv in enumerate(series):
        sel = props[props["level"].isna()] if lv is None else props[props["level"] == lv]
        xs, est, lo, hi, txt = [], [], [], [], []
        for ci, cid in enumerate(cond_ids):
            row = sel[sel["condition"] == cid]
            if row.empty:
                continue
            r = row.iloc[0]
            xs.append(ci + (li - (len(series) - 1) / 2) * width)
            est.append(r["estimate"])
            # Clip rounding noise: an interval ending at the estimate gives a zero (never negative) arm.
            lo.append(max(r["estimate"] - r["ci_low"], 0.0))
            hi.append(max(r["ci_high"] - r["estimate"], 0.0))
            txt.append(f"{int(r['successes'])}/{int(r['chances'])}")
        color = PALETTE[li % len(PALETTE)]
        ax.bar(xs, est, width=width * 0.9, color=color, alpha=0.75, label=str(lv) if lv is not None else None)
        ax.errorbar(xs, est, yerr=[lo, hi], fmt="none", ecolor="black", elinewidth=1, capsize=3)
        for x, t in zip(xs, txt, strict=True):  # counts at the foot of each bar: the axis ends at 1
            ax.text(x, 0.015, t, ha="center", va="bottom", fontsize=6, rotation=90 if len(series) > 2 else 0)
    ax.set_xticks(range(len(cond_ids)), [_wrap(lbl, 16) for _, lbl in conditions])
    ax.set_ylim(0, 1)
    ax.set_ylabel(f"{label} (95% Wilson interval)")
    ax.grid(axis="y", alpha=0.3)
    if levels:
        ax.legend(fontsize=8, frameon=False, ncols=len(series), loc="lower center", bbox_to_anchor=(0.5, 1.0))
    fig.suptitle(title, fontsize=11)
    return fig


def _legend_below(fig: Figure, handles: Sequence[Any], labels: Sequence[str], **kw: Any) -> None:
    """One row of legend entries under the panels (a figure legend, not an axes one: it names every panel's
    colours once), in the report's small type."""
    fig.legend(list(handles), list(labels), loc="outside lower center", ncols=len(labels), fontsize=8, frameon=False,
               **kw)


def percent_change_figure(
    pct: pd.DataFrame,
    *,
    metrics: Sequence[tuple[str, str]],
    conditions: Sequence[tuple[str, str]],
    reference: str,
    title: str,
) -> Figure:
    """Bars of the percent change of each condition's mean against ``reference``, one panel per metric."""
    fig, axes = _figure(len(metrics), panel_w=3.6, panel_h=3.0, cols=min(4, len(metrics)))
    others = [(c, lbl) for c, lbl in conditions if c != reference]
    for ax, (mid, mlabel) in zip(axes, metrics, strict=True):
        sel = pct[pct["metric"] == mid]
        vals = [
            float(sel.loc[sel["level"] == c, "percent_change"].iloc[0]) if (sel["level"] == c).any() else np.nan
            for c, _ in others
        ]
        colors = [PALETTE[0] if v < 0 else PALETTE[1] for v in vals]
        ax.bar(range(len(others)), vals, color=colors, alpha=0.85)
        for i, v in enumerate(vals):
            if np.isfinite(v):
                ax.text(i, v, f"{v:+.1f}%", ha="center", va="bottom" if v >= 0 else "top", fontsize=8)
        ax.axhline(0, color="black", linewidth=0.8)
        ax.set_xticks(range(len(others)), [lbl for _, lbl in others])
        ax.set_title(mlabel, fontsize=10)
        ax.set_ylabel(f"% change vs {reference}")
        ax.grid(axis="y", alpha=0.3)
        lo, hi = np.nanmin(vals + [0]), np.nanmax(vals + [0])
        pad = 0.2 * ((hi - lo) or 10)
        ax.set_ylim(lo - pad, hi + pad)
    from matplotlib.patches import Patch

    _legend_below(fig, [Patch(color=PALETTE[0], alpha=0.85), Patch(color=PALETTE[1], alpha=0.85)],
                  [f"lower than {reference}", f"higher than {reference}"])
    fig.suptitle(title, fontsize=11)
    return fig


def likert_figure(
    answers: pd.DataFrame,
    *,
    items: Sequence[str],
    conditions: Sequence[tuple[str, str]],
    points: int,
    title: str,
    scale: Sequence[str] | None = None,
) -> Figure:
    """Diverging stacked bars: the share of each answer per item (panel) and condition (bar).

    ``answers`` columns: item, level (condition id), value (one answer, 1 … ``points``). Answers below the
    middle of the scale extend left, those above right, the middle one is split across zero, so the bars
    line up on the neutral point (Robbins & Heiberger 2011). Likert answers are ordinal: no means here.
    """
    from matplotlib import colormaps
    from matplotlib.patches import Patch

    cmap = colormaps["PuOr"]  # diverging and colour-blind safe (ColorBrewer)
    colors = [cmap(0.08 + 0.84 * k / max(points - 1, 1)) for k in range(points)][::-1]
    if points % 2:  # the middle answer in grey: PuOr's centre is almost white
        colors[points // 2] = (0.78, 0.78, 0.78, 1.0)
    labels = list(scale) if scale and len(scale) == points else [str(k + 1) for k in range(points)]
    fig, axes = _figure(len(items), panel_w=4.6, panel_h=0.45 * len(conditions) + 1.1, cols=min(2, len(items)))
    mid = (points + 1) / 2
    for ax, item in zip(axes, items, strict=True):
        sel = answers[answers["item"] == item]
        ylabels = []
        for ci, (cid, clabel) in enumerate(conditions):
            vals = sel.loc[sel["level"] == cid, "value"].to_numpy(dtype=float)
            vals = np.round(vals[np.isfinite(vals)])
            n = len(vals)
            ylabels.append(f"{clabel} (n={n})")
            if not n:
                continue
            share = np.array([np.mean(vals == k + 1) * 100 for k in range(points)])
            left = -share[: int(math.floor(mid)) - 1].sum() - (share[int(mid) - 1] / 2 if mid == int(mid) else 0)
            for k in range(points):
                ax.barh(ci, share[k], left=left, color=colors[k], height=0.7, edgecolor="white", linewidth=0.4)
                left += share[k]
        ax.axvline(0, color="black", linewidth=0.8)
        ax.set_yticks(range(len(conditions)), ylabels, fontsize=8)
        ax.invert_yaxis()
        ax.set_xlim(-100, 100)
        ax.set_xticks([-100, -50, 0, 50, 100], ["100", "50", "0", "50", "100"], fontsize=8)
        ax.set_xlabel("% of answers (left: below the middle, right: above)", fontsize=8)
        ax.set_title(item.replace("_", " "), fontsize=10)
        ax.grid(axis="x", alpha=0.3)
    _legend_below(fig, [Patch(color=c) for c in colors], labels, title=f"answer (1–{points})", title_fontsize=8)
    fig.suptitle(title, fontsize=11)
    return fig


def trace_figure(
    traces: pd.DataFrame,
    *,
    panels: Sequence[str],
    channels: Sequence[tuple[str, str, str]],
    title: str,
    x_label: str = "time (s)",
    shade: str | None = None,
    threshold: float | None = None,
    right_limits: tuple[float, float] | None = (0.0, 105.0),
) -> Figure:
    """Time series per panel (condition): ``traces`` columns panel, x, and one column per channel.

    ``channels``: (column, label, axis) with axis "left" or "right" (a second y axis for commands, drawn
    within ``right_limits``). ``shade``: a boolean column whose true spans are shaded (tumour contact).
    ``threshold`` draws the contact threshold as a dotted line. One legend for the whole figure.
    """
    fig, axes = _figure(len(panels), panel_w=4.6, panel_h=2.9, cols=min(2, len(panels)))
    legend: dict[str, Any] = {}
    for ax, panel in zip(axes, panels, strict=True):
        sel = traces[traces["panel"] == panel]
        right = None
        for i, (col, lbl, side) in enumerate(channels):
            if col not in sel or sel[col].isna().all():
                continue
            target = ax
            if side == "right":
                right = right or ax.twinx()
                target = right
            (h,) = target.plot(sel["x"], sel[col], color=PALETTE[i % len(PALETTE)], linewidth=1.2, label=lbl)
            legend.setdefault(lbl, h)
        if shade and shade in sel and sel[shade].any():
            x = sel["x"].to_numpy()
            on = sel[shade].to_numpy(dtype=bool)
            edges = np.flatnonzero(np.diff(np.r_[0, on.astype(int), 0]))
            for a, b in zip(edges[::2], edges[1::2], strict=True):
                ax.axvspan(x[a], x[min(b, len(x)) - 1], color="gray", alpha=0.15, linewidth=0)
        if threshold is not None:
            (h,) = ax.plot([], [], color="black", linestyle=":", linewidth=0.9, label="contact threshold")
            ax.axhline(threshold, color="black", linestyle=":", linewidth=0.9)
            legend.setdefault("contact threshold", h)
        ax.set_title(str(panel), fontsize=10)
        ax.set_xlabel(x_label)
        left = [lbl for _, lbl, side in channels if side == "left"]
        ax.set_ylabel(left[0] if len(left) == 1 else "value")
        if right is not None:
            rl = [lbl for _, lbl, side in channels if side == "right"]
            right.set_ylabel(rl[0] if len(rl) == 1 else "command (%)")
            if right_limits is not None:
                right.set_ylim(*right_limits)
        ax.grid(alpha=0.3)
    if legend:
        _legend_below(fig, list(legend.values()), list(legend))
    fig.suptitle(title, fontsize=11)
    return fig


def message_figure(text: str, *, title: str) -> Figure:
    """A placeholder figure that says why the real one could not be drawn (never a silent gap)."""
    fig, (ax,) = _figure(1, panel_w=6, panel_h=2)
    ax.axis("off")
    ax.text(0.5, 0.5, text, ha="center", va="center", wrap=True, fontsize=9)
    fig.suptitle(title, fontsize=11)
    return fig
