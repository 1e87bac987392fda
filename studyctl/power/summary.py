"""Power per test and sample size from the replicates' rows: fraction significant with a Wilson interval,
and the distribution of the effect sizes.

Power counts a row as significant when the analysis runner said so (``significant`` is True: p, or the
adjusted p, below the plan's alpha). A test row a replicate did not produce (a post-hoc comparison that
runs only after a significant omnibus test) or could not compute counts as not significant, so the
power of a post-hoc pair is the chance that the whole procedure finds it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from studyctl.stats import wilson_interval

KEY = ("test_id", "role", "kind", "test", "metric", "split", "groups", "parent")
QUANTILES = (0.025, 0.25, 0.5, 0.75, 0.975)
#: Columns of :meth:`PowerTable.to_frame`.
COLUMNS = (
    "participants",
    *KEY,
    "replicates",
    "computed",
    "significant",
    "power",
    "power_ci_low",
    "power_ci_high",
    "ci_level",
    "p_median",
    "effect_size_name",
    "effect_n",
    "effect_mean",
    "effect_sd",
    "effect_q025",
    "effect_q25",
    "effect_median",
    "effect_q75",
    "effect_q975",
)


@dataclass(frozen=True)
class PowerTable:
    """Power of every test row at every sample size (``to_frame()`` has :data:`COLUMNS`)."""

    frame: pd.DataFrame
    sizes: tuple[int, ...]
    replicates: int

    def to_frame(self) -> pd.DataFrame:
        return self.frame.copy()

    def curve(self, test_id: str, metric: str | None = None) -> pd.DataFrame:
        """Rows of one test (and metric) ordered by sample size."""
        f = self.frame[self.frame["test_id"] == test_id]
        if metric is not None:
            f = f[f["metric"] == metric]
        return f.sort_values(["metric", "split", "groups", "participants"]).reset_index(drop=True)


def summarise(
    rows: pd.DataFrame, sizes: tuple[int, ...], replicates: dict[int, int] | int, confidence: float = 0.95
) -> PowerTable:
    """Aggregate per-replicate test rows into power and effect-size distributions.

    Parameters
    ----------
    rows
        Per-replicate rows (:data:`studyctl.power.replicate.ROW_COLUMNS`).
    sizes
        The sample sizes to report (in this order).
    replicates
        Replicates finished per sample size (the denominator of power), or one number for all.
    confidence
        Level of the Wilson intervals.
    """
    per_size = replicates if isinstance(replicates, dict) else {n: int(replicates) for n in sizes}
    rows = _keyed(rows)
    keys = _row_keys(rows)
    shown = _shown_levels(rows)
    out = []
    for n in sizes:
        total = int(per_size.get(n, 0))
        at_n = rows[rows["participants"] == n]
        groups = {k: g for k, g in at_n.groupby(list(KEY), sort=False, dropna=False)} if not at_n.empty else {}
        for key in keys:
            g = groups.get(key)
            sig = 0 if g is None else int((g["significant"] == True).sum())  # noqa: E712 - object column
            computed = 0 if g is None else int(g["p"].notna().sum())
            ci = wilson_interval(sig, total, confidence)
            eff = np.array([], dtype=float) if g is None else g["effect_size"].to_numpy(dtype=float)
            eff = eff[np.isfinite(eff)]
            qs = np.quantile(eff, QUANTILES) if eff.size else np.full(len(QUANTILES), np.nan)
            name = "" if g is None else next((s for s in g["effect_size_name"] if s), "")
            p = np.array([], dtype=float) if g is None else g["p"].to_numpy(dtype=float)
            p = p[np.isfinite(p)]
            fields = dict(zip(KEY, key, strict=True))
            if not fields["kind"]:
                fields["kind"], fields["groups"] = shown.get(key, ("", ""))
            out.append({
                "participants": n, **fields, "replicates": total, "computed": computed,
                "significant": sig, "power": ci.estimate, "power_ci_low": ci.lower, "power_ci_high": ci.upper,
                "ci_level": confidence, "p_median": float(np.median(p)) if p.size else np.nan,
                "effect_size_name": name, "effect_n": int(eff.size),
                "effect_mean": float(eff.mean()) if eff.size else np.nan,
                "effect_sd": float(eff.std(ddof=1)) if eff.size > 1 else np.nan,
                **{c: float(q) for c, q in zip(COLUMNS[-5:], qs, strict=True)},
            })
    frame = pd.DataFrame(out, columns=list(COLUMNS))
    return PowerTable(frame=frame, sizes=tuple(sizes), replicates=max(per_size.values(), default=0))


def _keyed(rows: pd.DataFrame) -> pd.DataFrame:
    """Rows with ``kind`` and ``groups`` blanked where they are not part of a test's identity.

    An omnibus or two-sample row is one test per (test, metric, split) whatever levels had data in a
    replicate (``groups`` lists them, and a row that could not be computed may say ``omnibus`` for a
    two-sample test); a pairwise or post-hoc row is identified by its pair.
    """
    out = rows.copy()
    single = out["kind"].isin(("omnibus", "two_sample"))
    out["shown_kind"], out["shown_levels"] = out["kind"], out["groups"]
    out.loc[single, "groups"] = ""
    out.loc[single, "kind"] = ""
    # A factorial test (ART ANOVA, mixed model) gives several omnibus rows per replicate, one per term (group,
    # condition, group × condition) named in ``groups``: those stay separate tests.
    terms = out.duplicated(subset=["participants", "replicate", *KEY], keep=False) & single
    out.loc[terms, "groups"] = out.loc[terms, "shown_levels"]
    out.loc[terms, "kind"] = out.loc[terms, "shown_kind"]
    return out


def _shown_levels(rows: pd.DataFrame) -> dict[tuple, tuple[str, str]]:
    """For keys with blanked kind and groups: the (kind, levels) of computed rows seen most often."""
    out: dict[tuple, tuple[str, str]] = {}
    single = rows[rows["kind"] == ""]
    for key, g in single.groupby(list(KEY), sort=False, dropna=False):
        ok = g[g["status"] == "ok"]
        pick = ok if not ok.empty else g
        counts = pick[["shown_kind", "shown_levels"]].value_counts()
        out[tuple(key)] = tuple(counts.index[0]) if not counts.empty else ("", "")
    return out


def _row_keys(rows: pd.DataFrame) -> list[tuple]:
    """Distinct test rows in the order the plan produces them (first appearance)."""
    if rows.empty:
        return []
    seen: dict[tuple, None] = {}
    for key in rows[list(KEY)].itertuples(index=False, name=None):
        seen.setdefault(tuple(key), None)
    return list(seen)
