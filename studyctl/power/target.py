"""The sample size for a target power: per test, the smallest size run whose power reaches the target.

Only sizes that complete the protocol's counterbalancing blocks qualify (every Williams sequence or explicit
order used equally often, within each stratum when the protocol counterbalances within strata): a study of
another size is unbalanced, so its power is not the power of the design. :func:`check_complete_blocks`
rejects such sizes before any simulation; :func:`smallest_sizes` reads the answer off a power table. The
interval is the Wilson interval of the power at that size over its replicate studies (Monte-Carlo error).
"""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from studyctl.errors import UsageError
from studyctl.protocol import Planner, allocate_strata

#: Columns of :meth:`TargetTable.to_frame`.
COLUMNS = (
    "test_id", "test", "kind", "metric", "split", "groups", "target", "participants", "reached", "power",
    "power_ci_low", "power_ci_high", "replicates", "largest_run", "power_at_largest",
)


def check_target(target: float | None) -> float | None:
    """``target`` must be a power strictly between 0 and 1 (None: no target)."""
    if target is None:
        return None
    if isinstance(target, bool) or not isinstance(target, int | float) or not 0.0 < float(target) < 1.0:
        raise UsageError(f"--target {target!r}: a target power must lie strictly between 0 and 1 (e.g. --target 0.8)")
    return float(target)


def block_period(protocol) -> tuple[int, bool]:  # noqa: ANN001 - a Protocol
    """(participants per complete counterbalancing block, whether blocks are counted per stratum).

    1 when the scheme has no fixed sequences (``random``: every size is balanced in expectation).
    """
    planner = Planner(protocol)
    if planner.sequences is None:
        return 1, False
    period = len(planner.sequences) * (planner.block_size if planner.allocation == "blocked" else 1)
    return period, bool(planner.within_strata) and len(protocol.stratum_ids) > 1


def completes_blocks(protocol, n: int) -> bool:  # noqa: ANN001 - a Protocol
    """Whether ``n`` participants (allocated to strata as a simulated study does) fill whole blocks."""
    period, per_stratum = block_period(protocol)
    if period == 1:
        return True
    if not per_stratum:
        return n % period == 0
    counts: dict[str, int] = {}
    for stratum, _slot in allocate_strata(protocol, n):
        counts[stratum] = counts.get(stratum, 0) + 1
    return all(c % period == 0 for c in counts.values()) and len(counts) == len(protocol.stratum_ids)


def allowed_sizes(protocol, up_to: int, count: int = 6) -> list[int]:  # noqa: ANN001 - a Protocol
    """The first ``count`` sizes that complete the blocks, searching to at least ``up_to``."""
    out: list[int] = []
    n = 1
    while len(out) < count and n <= max(up_to, 1) * 4 + 400:
        if completes_blocks(protocol, n):
            out.append(n)
        n += 1
    return out


def check_complete_blocks(protocol, sizes: tuple[int, ...]) -> None:  # noqa: ANN001 - a Protocol
    """UsageError naming the sizes that leave a counterbalancing block incomplete, what is allowed, the fix."""
    bad = [n for n in sizes if not completes_blocks(protocol, n)]
    if not bad:
        return
    period, per_stratum = block_period(protocol)
    scope = f"in each of its {len(protocol.stratum_ids)} strata" if per_stratum else "in the study"
    ok = allowed_sizes(protocol, max(sizes))
    raise UsageError(
        f"--participants {', '.join(map(str, bad))}: with --target only sizes that complete the counterbalancing "
        f"blocks of protocol {protocol.study.id!r} count ({protocol.counterbalance.scheme}: blocks of {period} "
        f"participants {scope}); allowed sizes start {', '.join(map(str, ok))}: use e.g. --participants "
        f"{','.join(map(str, ok[:5]))}"
    )


@dataclass(frozen=True)
class TargetTable:
    """Per test row: the smallest size run reaching ``target`` power (``participants`` None: none did)."""

    frame: pd.DataFrame
    target: float

    def to_frame(self) -> pd.DataFrame:
        return self.frame.copy()

    def to_records(self) -> list[dict]:
        f = self.frame.astype(object).where(self.frame.notna(), None)
        return f.to_dict(orient="records")


def smallest_sizes(table: pd.DataFrame, target: float, *, posthoc: bool = False) -> TargetTable:
    """From a power table (:data:`studyctl.power.summary.COLUMNS`): per test row, the smallest size whose power
    estimate reaches ``target``, with that size's Wilson interval (post-hoc pairs only when ``posthoc``)."""
    target = check_target(target)
    keys = ["test_id", "test", "kind", "metric", "split", "groups"]
    f = table.copy()
    for col in keys:
        f[col] = f[col].fillna("").astype(str)
    if not posthoc:
        f = f[f["kind"] != "posthoc"]
    out = []
    for key, g in f.groupby(keys, sort=False):
        g = g.sort_values("participants")
        hit = g[g["power"] >= target]
        last = g.iloc[-1]
        row = dict(zip(keys, key, strict=True))
        row.update(target=target, largest_run=int(last["participants"]), power_at_largest=float(last["power"]))
        if hit.empty:
            row.update(participants=None, reached=False, power=None, power_ci_low=None, power_ci_high=None,
                       replicates=int(last["replicates"]))
        else:
            h = hit.iloc[0]
            row.update(participants=int(h["participants"]), reached=True, power=float(h["power"]),
                       power_ci_low=float(h["power_ci_low"]), power_ci_high=float(h["power_ci_high"]),
                       replicates=int(h["replicates"]))
        out.append(row)
    frame = pd.DataFrame(out, columns=list(COLUMNS))
    frame["participants"] = frame["participants"].astype("Int64")  # a whole number, or <NA> when not reached
    return TargetTable(frame=frame, target=target)
