"""The analysis units of a pool's people, computed once: a stage-2 replicate's units are its people's rows.

:func:`studyctl.analysis.shape.unit_values` keys every unit by participant first and keeps groups in order of
appearance, and the plan's data preparation (metric renaming, planned conditions, the missing-data policy) works
row by row or person by person. So the units of a replicate study made of pool people a, b, c … are exactly the
rows of a, then b, then c … of the units of the whole pool: :class:`PoolUnits` computes those once per
(metric, keep columns) and a replicate only gathers row positions. :func:`replicate_rows` gives the same test
rows :func:`studyctl.analysis.execute.hypothesis_rows` gives for the replicate's own table (tests/power check that).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from studyctl.analysis.execute import UnitSource, hypothesis_rows
from studyctl.analysis.results import TestRow
from studyctl.analysis.shape import Prepared, prepare, unit_values
from studyctl.analysis.table import MetricTable


def _positions(column: pd.Series) -> dict[str, np.ndarray]:
    """Row positions of each value of ``column`` (in row order)."""
    codes, names = pd.factorize(column, sort=False)
    order = np.argsort(codes, kind="stable")
    bounds = np.searchsorted(codes[order], np.arange(len(names) + 1))
    return {str(name): order[bounds[i]:bounds[i + 1]] for i, name in enumerate(names)}


class PoolUnits:
    """A pool's prepared metric rows and, per (metric, keep columns), its units, indexed by person."""

    def __init__(self, plan, metrics: pd.DataFrame, study: str = "") -> None:  # noqa: ANN001
        self.plan = plan
        # "fail" stops the whole analysis when any one person lacks a value: a pool-wide preparation would fail
        # for a person a replicate never draws, so such plans prepare each replicate's own table instead.
        self.per_replicate = plan.missing == "fail"
        self._table = MetricTable(frame=metrics, source="two-stage pool", study=study)
        self._prep = None if self.per_replicate else prepare(plan, self._table)
        self._units: dict[tuple, tuple[pd.DataFrame, dict[str, np.ndarray]]] = {}
        if self._prep is not None:
            frame = self._prep.frame
            self._rows = _positions(frame["participant"])
            # prepare() lays rows out metric by metric (in the plan's order), people in order within a metric
            self._metric_code = pd.factorize(frame["metric"], sort=False)[0]

    def _gather(self, pos: dict[str, np.ndarray], chosen: Sequence[str]) -> np.ndarray:
        parts = [pos[m] for m in chosen if m in pos]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.intp)

    @staticmethod
    def _labels(pos: dict[str, np.ndarray], chosen: Sequence[str]) -> np.ndarray | None:
        """Per gathered row, its person's label in the replicate when someone is drawn twice (a replicate of
        a bootstrap pool): the second copy is another participant, ``member~1`` (None: nobody repeats)."""
        if len(set(chosen)) == len(chosen):
            return None
        seen: dict[str, int] = {}
        labels = []
        for m in chosen:
            if m in pos:
                k = seen.get(m, 0)
                seen[m] = k + 1
                labels.append(np.full(len(pos[m]), m if k == 0 else f"{m}~{k}", dtype=object))
        return np.concatenate(labels) if labels else None

    def view(self, chosen: Sequence[str], by_member: dict[str, pd.DataFrame]) -> tuple[Prepared, UnitSource | None]:
        """The prepared data of a replicate made of ``chosen`` (in that order) and where its units come from."""
        if self._prep is None:
            frames, seen = [], {}
            for m in chosen:
                if m in by_member:
                    k = seen[m] = seen.get(m, -1) + 1
                    frames.append(by_member[m] if k == 0 else by_member[m].assign(participant=f"{m}~{k}"))
            frame = pd.concat(frames, ignore_index=True)
            return prepare(self.plan, MetricTable(frame=frame, source="two-stage pool", study=self._table.study)), None
        idx = self._gather(self._rows, chosen)
        labels = self._labels(self._rows, chosen)
        order = np.argsort(self._metric_code[idx], kind="stable")
        idx = idx[order]
        frame = self._prep.frame.take(idx).reset_index(drop=True)
        if labels is not None:
            frame["participant"] = labels[order]
        prep = Prepared(frame, self._prep.missing.iloc[0:0], (), ())

        def units(metric: str, kind: str, keep: list[str], aggregate: str, data: pd.DataFrame) -> pd.DataFrame:
            key = (metric, kind, tuple(keep), aggregate)
            if key not in self._units:
                whole = self._prep.frame[self._prep.frame["metric"] == metric]
                table = unit_values(whole, kind=kind, keep=keep, aggregate=aggregate)
                self._units[key] = (table, _positions(table["participant"]))
            table, pos = self._units[key]
            out = table.take(self._gather(pos, chosen)).reset_index(drop=True)
            labels = self._labels(pos, chosen)
            if labels is not None:
                out["participant"] = labels
            return out

        return prep, units


def replicate_rows(pool_units: PoolUnits, chosen: Sequence[str],
                   by_member: dict[str, pd.DataFrame]) -> tuple[TestRow, ...]:
    """The plan's hypothesis-test rows for the replicate study made of the pool people ``chosen``."""
    prep, units = pool_units.view(chosen, by_member)
    return hypothesis_rows(pool_units.plan, prep, units=units)
