"""Number formatting and colours shared by tables, figures and documents (no matplotlib here)."""

from __future__ import annotations

import math

# Colour-blind-safe (Okabe-Ito) palette; the first colours go to groups / levels in plan order.
PALETTE = ("#0072B2", "#E69F00", "#009E73", "#CC79A7", "#56B4E9", "#D55E00", "#F0E442", "#000000")


def fmt_p(p: float) -> str:
    """A p-value as papers print it: 3 significant digits, scientific below 0.001, never a fake 0."""
    if p is None or (isinstance(p, float) and math.isnan(p)):
        return "–"
    if p == 0:
        return "< 1e-300"
    if p < 1e-3:
        mant, exp = f"{p:.2e}".split("e")
        return f"{mant}e{int(exp)}"
    return f"{p:.3g}" if p < 0.1 else f"{p:.3f}"


def fmt_num(x: float, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    if isinstance(x, float) and math.isinf(x):
        return "∞" if x > 0 else "−∞"
    if x != 0 and (abs(x) >= 1e5 or abs(x) < 1e-3):
        return f"{x:.{digits}g}"
    return f"{x:.{digits}g}" if abs(x) < 1 else f"{x:.{max(digits, len(str(int(abs(x)))))}g}"


def stars(p: float) -> str:
    """Significance marks: * < 0.05, ** < 0.01, *** < 0.001 ('' otherwise)."""
    if p is None or not (p == p):  # NaN
        return ""
    return "***" if p < 1e-3 else "**" if p < 1e-2 else "*" if p < 0.05 else ""
