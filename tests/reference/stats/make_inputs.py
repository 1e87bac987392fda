"""Write inputs.csv: the fixed data sets that r_reference.R and the tests both read.

Run: python tests/reference/stats/make_inputs.py  (numpy default_rng(20260521); committed output)
"""

from pathlib import Path

import numpy as np

rng = np.random.default_rng(20260521)
rows = []


def add(dataset, group, values):
    for v in values:
        rows.append(f"{dataset},{group},{float(v)!r}")


add("mw_a", "x", np.round(rng.normal(10, 2, 12), 3))
add("mw_a", "y", np.round(rng.normal(11.5, 2, 15), 3))
add("mw_sep", "x", np.arange(1, 21) + 20.5)
add("mw_sep", "y", np.arange(1, 21) + 0.25)
add("mw_ties", "x", rng.integers(1, 6, 30))
add("mw_ties", "y", rng.integers(2, 7, 28))
add("mw_big", "x", np.round(rng.normal(0, 1, 60), 4))
add("mw_big", "y", np.round(rng.normal(0.5, 1, 55), 4))
add("sr_a", "d", np.round(rng.normal(0.6, 1, 15), 3))
add("sr_ties", "d", rng.integers(-3, 6, 25))
for i, (n, shift) in enumerate([(8, 0.0), (10, 0.5), (9, 1.0), (12, 0.2)]):
    add("kw_a", f"g{i + 1}", np.round(rng.normal(shift, 1, n), 1))
for i, p in enumerate([(0.1, 0.2, 0.3, 0.2, 0.2), (0.05, 0.15, 0.3, 0.3, 0.2), (0.2, 0.3, 0.3, 0.1, 0.1)]):
    add("kw_likert", f"g{i + 1}", rng.choice(np.arange(1, 6), size=20, p=p))
for i in range(5):
    add("anova_5x12", f"g{i + 1}", np.round(rng.normal(10 + 0.6 * i, 1.5, 12), 3))
for i, n in enumerate([6, 9, 7, 10]):
    add("anova_unequal", f"g{i + 1}", np.round(rng.normal(5 + 0.8 * i, 1.2, n), 2))
add("warp", "L", [26, 30, 54, 25, 70, 52, 51, 26, 67, 27, 14, 29, 19, 29, 31, 41, 20, 44])
add("warp", "M", [18, 21, 29, 17, 12, 18, 35, 30, 36, 42, 26, 19, 16, 39, 28, 21, 39, 29])
add("warp", "H", [36, 21, 24, 18, 10, 43, 28, 15, 26, 20, 21, 24, 17, 13, 15, 15, 16, 28])
base = np.round(rng.normal(20, 4, 10), 1)
for i in range(4):
    add("rm_4x10", f"c{i + 1}", np.round(base + rng.normal(0.8 * i, 1.5, 10), 1))

out = Path(__file__).with_name("inputs.csv")
out.write_text("dataset,group,value\n" + "\n".join(rows) + "\n")
print(f"wrote {len(rows)} rows to {out}")
