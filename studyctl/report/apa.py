"""Results as a journal prints them (APA style): ``F(4, 55) = 174.2, p < .001, η² = .93``.

Pure string formatting of one row of the tests table (:data:`studyctl.analysis.results.ROW_COLUMNS`);
no test is re-run here. p is never printed in scientific notation: below .001 it is ``p < .001``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

#: Effect sizes as printed, by the name a result gives them.
EFFECT_SYMBOLS = {
    "eta_squared": "η²",
    "omega_squared": "ω²",
    "partial_eta_squared": "η²p",
    "generalized_eta_squared": "η²G",
    "epsilon_squared": "ε²",
    "kendall_w": "W",
    "rank_biserial": "r_rb",
    "matched_pairs_r": "r",
    "mean_difference": "Δ",
    "mean_rank_difference": "Δ mean rank",
    "difference": "Δp",
    "odds_ratio": "OR",
    "cohens_d": "d",
    "r_squared_marginal": "R²m",
    "nagelkerke_r2": "R²N",
}

#: Statistics as printed, by the name a result gives them.
STAT_SYMBOLS = {"chi2 (Friedman)": "χ²", "V (R+)": "V", "chi2": "χ²", "chi2 (LR)": "χ²", "W = min(R+, R-)": "W"}

# Effect sizes bounded by 1 in absolute value: printed without the leading zero (APA).
_BOUNDED = {"eta_squared", "omega_squared", "partial_eta_squared", "generalized_eta_squared", "epsilon_squared",
            "kendall_w", "rank_biserial", "matched_pairs_r", "difference", "r_squared_marginal",
            "nagelkerke_r2"}


def _nan(x: Any) -> bool:
    return x is None or (isinstance(x, float) and math.isnan(x))


def p_text(p: float, *, name: str = "p") -> str:
    """``p = .023``, ``p < .001``, ``p > .999`` (three decimals, no leading zero); '' for NaN."""
    if _nan(p):
        return ""
    if p < 0.001:
        return f"{name} < .001"
    if p > 0.999:
        return f"{name} > .999"
    return f"{name} = {f'{p:.3f}'.removeprefix('0')}"


def bounded(x: float, digits: int = 2) -> str:
    """A value within [−1, 1] without its leading zero: ``.93``, ``−.41``."""
    text = f"{abs(x):.{digits}f}".removeprefix("0")
    return ("−" if x < 0 and text.strip("0.") else "") + text


def number(x: float) -> str:
    """A statistic: whole numbers as such, else 2 decimals (1 from 100 on, 3 significant digits below .01)."""
    if _nan(x):
        return "–"
    if math.isinf(x):
        return "∞" if x > 0 else "−∞"
    sign = "−" if x < 0 else ""
    a = abs(x)
    if a == round(a) and a < 1e6:
        return f"{sign}{a:.0f}"
    if a >= 1e5:
        return f"{sign}{a:.3g}"
    if a >= 100:
        return f"{sign}{a:.1f}"
    if a < 0.01:
        return f"{sign}{a:.2g}"
    return f"{sign}{a:.2f}"


def df_text(df: float) -> str:
    return "" if _nan(df) else (f"{df:.0f}" if df == round(df) else f"{df:.2f}")


def effect_text(name: str, value: float) -> str:
    if not name or _nan(value):
        return ""
    sym = EFFECT_SYMBOLS.get(name, name.replace("_", " "))
    return f"{sym} = {bounded(value) if name in _BOUNDED and abs(value) <= 1 else number(value)}"


def ci_text(low: float, high: float, level: float, *, bounded_scale: bool = False) -> str:
    if _nan(low) or _nan(high):
        return ""
    fmt = bounded if bounded_scale else number
    pct = f"{level * 100:.0f}% " if not _nan(level) else ""
    return f"{pct}CI [{fmt(low)}, {fmt(high)}]"


def line(row: Mapping[str, Any]) -> str:
    """The APA line of one row of the tests table ('' when the row has nothing to print)."""
    if row.get("status", "ok") != "ok":
        return "not computed"
    kind = row.get("kind", "")
    test = row.get("test", "")
    es_name = row.get("effect_size_name", "") or ""
    if kind == "interval":  # one proportion with its interval
        est = row.get("estimate")
        if _nan(est):
            return ""
        return f"p̂ = {bounded(est)}, " + ci_text(row["ci_low"], row["ci_high"], row.get("ci_level"),
                                                   bounded_scale=True)
    if test == "newcombe":
        return f"Δp = {bounded(row['estimate'])}, " + ci_text(row["ci_low"], row["ci_high"], row.get("ci_level"),
                                                             bounded_scale=True)
    parts: list[str] = []
    name = row.get("statistic_name", "") or ""
    stat = row.get("statistic")
    if es_name == "mean_difference" and name.startswith("diff"):  # Tukey: the difference is the estimate
        parts.append(f"Δ = {number(stat)}")
        ci = ci_text(row.get("ci_low"), row.get("ci_high"), row.get("ci_level"))
        if ci:
            parts.append(ci)
        es_name = ""
    elif name and not _nan(stat):
        sym = STAT_SYMBOLS.get(name, name)
        df, df2 = row.get("df"), row.get("df2")
        if not _nan(df) and not _nan(df2):
            sym += f"({df_text(df)}, {df_text(df2)})"
        elif not _nan(df) and sym in ("H", "χ²"):
            sym += f"({df_text(df)})"
        parts.append(f"{sym} = {number(stat)}")
        if not _nan(row.get("critical_value")):
            parts.append(f"W_crit = {number(row['critical_value'])}, n = {df_text(df)}")
    z = row.get("z")
    if not _nan(z) and name not in ("z",):
        parts.append(f"z = {number(z)}")
    p, p_adj = row.get("p"), row.get("p_adj")
    method = row.get("p_adjust", "") or ""
    if not _nan(p):
        parts.append(p_text(p))
    if not _nan(p_adj) and method not in ("", "none"):
        parts.append(p_text(p_adj, name=f"p_{method}"))
    es = effect_text(es_name, row.get("effect_size"))
    if es:
        lo, hi = row.get("effect_ci_low"), row.get("effect_ci_high")
        if not _nan(lo) and not _nan(hi):  # a bootstrap interval of the effect size, when the report has one
            fmt = bounded if es_name in _BOUNDED else number
            es += f" [{fmt(lo)}, {fmt(hi)}]"
        parts.append(es)
    return ", ".join(parts)
