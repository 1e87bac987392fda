"""Independent exact references for tests/stats (no studyctl code is imported).

Run from the repository root: python tests/reference/stats/exact_reference.py
Writes exact_reference.csv (tool versions in the header). Methods:
* rank-sum / signed-rank exact conditional p-values with ties: brute-force enumeration of all
  subsets / sign vectors where feasible, else an exact-integer (Python int) dictionary DP — the
  same quantity coin::wilcox_test(distribution = "exact") computes;
* untied rank-sum tails at 60×70 and 200×200: exact integer Gaussian-binomial coefficients;
* Newcombe (1998) Table II, method 10, and Wilson limits in 40-digit mpmath;
* studentized range tails: nested mpmath quadrature (30 digits).
"""

from __future__ import annotations

import csv
import itertools
import platform
import sys
from collections import defaultdict
from fractions import Fraction
from math import comb
from pathlib import Path

import mpmath as mp

HERE = Path(__file__).parent
rows: list[tuple[str, str, str]] = []


def put(case: str, key: str, value) -> None:
    rows.append((case, key, mp.nstr(mp.mpf(value), 20) if not isinstance(value, str) else value))


def inputs() -> dict[str, dict[str, list[float]]]:
    data: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    with open(HERE / "inputs.csv") as fh:
        for r in csv.DictReader(fh):
            data[r["dataset"]][r["group"]].append(float(r["value"]))
    return data


def doubled_midranks(values: list[float]) -> list[int]:
    order = sorted(range(len(values)), key=lambda i: values[i])
    r2 = [0] * len(values)
    i = 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and values[order[j + 1]] == values[order[i]]:
            j += 1
        for t in range(i, j + 1):
            r2[order[t]] = (i + 1) + (j + 1)
        i = j + 1
    return r2


def subset_sum_counts(r2: list[int], m: int) -> dict[int, int]:
    """Number of m-subsets of r2 by sum (exact integers)."""
    dp = [defaultdict(int) for _ in range(m + 1)]
    dp[0][0] = 1
    for r in r2:
        for k in range(m - 1, -1, -1):
            for s, c in list(dp[k].items()):
                dp[k + 1][s + r] += c
    return dp[m]


def ranksum_p(x: list[float], y: list[float], brute: bool) -> dict[str, Fraction]:
    r2 = doubled_midranks(x + y)
    m, n_total = len(x), len(x) + len(y)
    t = sum(r2[:m])
    mean2 = Fraction(m * (n_total + 1))
    if brute:
        counts: dict[int, int] = defaultdict(int)
        for sub in itertools.combinations(r2, m):
            counts[sum(sub)] += 1
    else:
        counts = subset_sum_counts(r2, m)
    total = comb(n_total, m)
    less = Fraction(sum(c for s, c in counts.items() if s <= t), total)
    greater = Fraction(sum(c for s, c in counts.items() if s >= t), total)
    two = Fraction(sum(c for s, c in counts.items() if abs(s - mean2) >= abs(t - mean2)), total)
    return {"less": less, "greater": greater, "two.sided": two}


def signedrank_p(d: list[float], zero_method: str, brute: bool) -> dict[str, Fraction]:
    if zero_method == "wilcox":
        d = [v for v in d if v != 0]
        r2 = doubled_midranks([abs(v) for v in d])
    else:  # pratt: rank with zeros, then drop them
        r_all = doubled_midranks([abs(v) for v in d])
        r2 = [r for r, v in zip(r_all, d, strict=True) if v != 0]
        d = [v for v in d if v != 0]
    t = sum(r for r, v in zip(r2, d, strict=True) if v > 0)
    total_sum = sum(r2)
    if brute:
        counts: dict[int, int] = defaultdict(int)
        for signs in itertools.product((0, 1), repeat=len(r2)):
            counts[sum(r for r, s in zip(r2, signs, strict=True) if s)] += 1
    else:
        counts = {0: 1}
        for r in r2:
            new: dict[int, int] = defaultdict(int)
            for s, c in counts.items():
                new[s] += c
                new[s + r] += c
            counts = new
    total = 2 ** len(r2)
    mean2 = Fraction(total_sum, 2)
    return {
        "less": Fraction(sum(c for s, c in counts.items() if s <= t), total),
        "greater": Fraction(sum(c for s, c in counts.items() if s >= t), total),
        "two.sided": Fraction(sum(c for s, c in counts.items() if abs(s - mean2) >= abs(t - mean2)), total),
    }


def gaussian_binomial_lower(m: int, n: int, us: list[int]) -> dict[int, Fraction]:
    """P(U ≤ u) without ties from exact integer coefficients of [m+n choose m]_q."""
    length = m * n + 1
    p = [0] * length
    p[0] = 1
    for i in range(1, m + 1):
        for k in range(i, length):
            p[k] += p[k - i]
        d = n + i
        for k in range(length - 1, d - 1, -1):
            p[k] -= p[k - d]
    total = comb(m + n, m)
    out, acc, want = {}, 0, set(us)
    for u in range(max(us) + 1):
        acc += p[u]
        if u in want:
            out[u] = Fraction(acc, total)
    return out


def main() -> None:
    data = inputs()
    fr = lambda f: mp.mpf(f.numerator) / f.denominator  # noqa: E731
    mp.mp.dps = 40
    # rank-sum, exact conditional with ties
    for name, x, y, brute in [
        ("case12", list(range(1, 11)), list(range(2, 25, 2)), True),
        ("mw_ties", data["mw_ties"]["x"], data["mw_ties"]["y"], False),
        ("small_ties", [1, 2, 2, 3, 5, 5], [2, 3, 3, 4, 6, 6, 7], True),
    ]:
        for alt, p in ranksum_p([float(v) for v in x], [float(v) for v in y], brute).items():
            put(f"ranksum_exact:{name}", alt, fr(p))
    # signed-rank, exact conditional with ties/zeros
    for name, d, zm, brute in [
        ("tie5", [1, 1, 2, 3, 4], "wilcox", True),
        ("zero5", [0, 1, 2, 3, 4], "wilcox", True),
        ("zero5_pratt", [0, 1, 2, 3, 4], "pratt", True),
        ("mixed12", [1, 1, 2, -2, 3, 0, 4, -1, 5, 5, 6, 0], "pratt", True),
        ("sr_ties", data["sr_ties"]["d"], "wilcox", False),
        ("sr_ties_pratt", data["sr_ties"]["d"], "pratt", False),
    ]:
        for alt, p in signedrank_p([float(v) for v in d], zm, brute).items():
            put(f"signedrank_exact:{name}", alt, fr(p))
    # untied rank-sum tails from exact integers
    for m, n, us in [(60, 70, [0, 50, 700, 1500, 2100]), (200, 200, [0, 100, 5000, 15000, 19999, 20000])]:
        for u, p in gaussian_binomial_lower(m, n, us).items():
            put(f"ranksum_untied:{m}x{n}", f"le_{u}", fr(p))
    # Wilson and Newcombe (1998) Table II, method 10
    z = mp.sqrt(2) * mp.erfinv(mp.mpf("0.95"))

    def wilson(x: int, n: int):
        x, n = mp.mpf(x), mp.mpf(n)
        c = (x + z * z / 2) / (n + z * z)
        h = z * mp.sqrt(x * (n - x) / n + z * z / 4) / (n + z * z)
        return x / n, c - h, c + h

    for x1, n1, x2, n2 in [(56, 70, 48, 80), (9, 10, 3, 10), (6, 7, 2, 7), (5, 56, 0, 29), (0, 10, 0, 20),
                           (10, 10, 0, 20), (50, 60, 47, 60), (50, 60, 30, 60), (47, 60, 30, 60)]:
        p1, l1, u1 = wilson(x1, n1)
        p2, l2, u2 = wilson(x2, n2)
        d = p1 - p2
        tag = f"newcombe:{x1}/{n1}-{x2}/{n2}"
        put(tag, "lower", d - mp.sqrt((p1 - l1) ** 2 + (u2 - p2) ** 2))
        put(tag, "upper", d + mp.sqrt((u1 - p1) ** 2 + (p2 - l2) ** 2))
    for x, n in [(0, 10), (10, 10), (81, 263), (15, 148), (1, 29), (50, 60), (30, 60), (47, 60), (1, 10**12)]:
        _, lo, hi = wilson(x, n)
        put(f"wilson:{x}:{n}", "lower", max(lo, 0))
        put(f"wilson:{x}:{n}", "upper", min(hi, 1))
    # studentized range tails (nested quadrature in mpmath)
    mp.mp.dps = 30

    def range_sf(w, k):
        w = mp.mpf(w)

        def h(zz):
            b = mp.ncdf(-zz)
            a = mp.ncdf(zz + w) - mp.ncdf(zz)
            return mp.npdf(zz) * mp.ncdf(-(zz + w)) * sum(b**i * a ** (k - 2 - i) for i in range(k - 1))

        # the integrand is negligible (< e^-60 of its peak) outside [min(c, −4) − 12, max(c, 0) + 12]
        c = -w / 2
        lo, hi = min(c, mp.mpf(-4)) - 12, max(c, mp.mpf(0)) + 12
        pts = [lo + (hi - lo) * j / 48 for j in range(49)]
        return k * mp.quad(h, pts, maxdegree=8)

    for w, k in [(3.3, 4), (8.0, 5), (30.0, 4), (1.0, 10)]:
        put(f"range_sf:{w}:{k}", "sf", range_sf(w, k))
    if "--fast" not in sys.argv:
        for q, k, df in [(3.5, 3, 10), (20.0, 3, 20), (40.0, 10, 100), (4.0, 5, 55)]:
            qq, dd = mp.mpf(q), mp.mpf(df)
            logc = mp.log(2) + dd / 2 * mp.log(dd / 2) - mp.loggamma(dd / 2)
            peak = mp.sqrt(dd / (dd + qq * qq / 2))
            sd = 1 / mp.sqrt(2 * dd + qq * qq)
            near = {peak + j * sd for j in (-12, -6, -3, -1, 0, 1, 3, 6, 12)}
            pts = sorted({mp.mpf(0), mp.inf} | {p for p in near if p > 0})
            val = mp.quad(lambda s: mp.exp(logc + (dd - 1) * mp.log(s) - dd * s * s / 2) * range_sf(qq * s, k), pts)  # noqa: B023
            put(f"ptukey_sf:{q}:{k}:{df}", "sf", val)
    out = HERE / "exact_reference.csv"
    with open(out, "w") as fh:
        fh.write(f"# python {platform.python_version()}, mpmath {mp.__version__}\n")
        fh.write("# generated by exact_reference.py (independent of studyctl)\n")
        fh.write("case,key,value\n")
        for r in rows:
            fh.write(",".join(r) + "\n")
    print(f"wrote {len(rows)} values to {out}")


if __name__ == "__main__":
    main()
