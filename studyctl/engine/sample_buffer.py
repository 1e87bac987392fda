"""A trial's samples on their way into the store: buffered in flat arrays, committed at least every second.

Used by :class:`~studyctl.engine.store_recorder.StoreRecorder` (``samples()``), the only writer of a session.
"""

from __future__ import annotations

import operator
import time
from array import array
from collections.abc import Mapping
from typing import Any

import numpy as np

from studyctl.errors import SessionError
from studyctl.store import StudyStore


def _tuple_getter(keys: tuple[str, ...]):
    """A function of a mapping returning its values at ``keys`` as a tuple (itemgetter returns a bare value
    for one key)."""
    if len(keys) > 1:
        return operator.itemgetter(*keys)
    if len(keys) == 1:
        key = keys[0]
        return lambda v: (v[key],)
    return lambda v: ()


class StoreSamples:
    """Buffers a trial's samples and commits them through the store's SampleWriter at least every second
    of wall time (``FLUSH_WALL_S``): a crash loses at most that much, as the store promises.

    On a simulated clock a second of wall time spans many simulated seconds, so committing by wall time
    (not by sample time) keeps virtual runs from committing every 50 samples.
    """

    FLUSH_WALL_S = 1.0

    def __init__(self, store: StudyStore, trial_id: int, guard=None) -> None:
        self._store = store
        self._trial = trial_id
        self._guard = guard  # the session lease's check, run inside every flush's transaction
        self._writer = None
        self._keys: tuple[str, ...] | None = None
        self._get = None
        self._parts: tuple | bool | None = None  # write_parts' plan; False: the parts overlap, always merge
        # Rows go straight into flat float64 buffers (no per-flush conversion of a list of tuples); a value
        # array('d') refuses (None, a string) switches to object rows that numpy converts as it always did.
        self._t = array("d")
        self._flat: array | None = array("d")
        self._rows: list[tuple[Any, ...]] = []
        self._last = time.monotonic()

    def write_parts(self, t: float, a: Mapping[str, float], b: Mapping[str, float], c: Mapping[str, float]) -> None:
        """``write(t, {**a, **b, **c})`` without building the merged dict every tick.

        The first call plans one getter per part (when the parts share no channel); a later tick takes that
        path only when every part has the planned length and all its planned keys (so exactly the planned key
        set), else it merges as ``write`` would: the row is the same either way."""
        plan = self._parts
        if plan:
            ga, na, gb, nb, gc, nc = plan
            if len(a) == na and len(b) == nb and len(c) == nc:
                try:
                    row = ga(a) + gb(b) + gc(c)
                except KeyError:
                    pass
                else:
                    self._append(t, row)
                    return
        self.write(t, {**a, **b, **c})
        if plan is None:
            self._plan_parts(a, b, c)

    def _plan_parts(self, a: Mapping[str, float], b: Mapping[str, float], c: Mapping[str, float]) -> None:
        ka, kb, kc = tuple(a), tuple(b), tuple(c)
        if len(set(ka) | set(kb) | set(kc)) != len(ka) + len(kb) + len(kc) or ka + kb + kc != self._keys:
            self._parts = False  # overlapping parts: always merge
            return
        self._parts = (_tuple_getter(ka), len(ka), _tuple_getter(kb), len(kb), _tuple_getter(kc), len(kc))

    def write(self, t: float, values: Mapping[str, float]) -> None:
        if self._get is None:
            self._keys = tuple(values)
            self._get = operator.itemgetter(*self._keys) if len(self._keys) > 1 else (lambda v: (v[self._keys[0]],))
        try:
            row = self._get(values)
        except KeyError as exc:
            raise SessionError(f"sample at t={t:g} s lacks channel {exc.args[0]!r} logged so far "
                               f"({', '.join(self._keys)}); a device or controller changed its channels") from None
        self._append(t, row)

    def _append(self, t: float, row: tuple[Any, ...]) -> None:
        flat = self._flat
        if flat is not None:
            n0 = len(flat)
            try:
                flat.extend(row)
            except (TypeError, ValueError, OverflowError):
                del flat[n0:]  # extend stops part-way
                self._to_rows()
                self._rows.append(row)
        else:
            self._rows.append(row)
        self._t.append(t)
        if time.monotonic() - self._last >= self.FLUSH_WALL_S:
            self.flush()

    def flush(self) -> None:
        self._last = time.monotonic()
        if not self._t:
            return
        if self._writer is None:
            # the writer's own flushing is disabled: this class decides when to commit
            # sealed with the trial's next record (the recorder seals per transaction), not per flush
            self._writer = self._store.sample_writer(self._trial, list(self._keys), flush_interval_s=1e12,
                                                     guard=self._guard, seal=False)
        t = np.frombuffer(self._t, dtype=float)
        if self._flat is not None:
            values = np.frombuffer(self._flat, dtype=float).reshape(len(t), len(self._keys))
        else:
            values = np.asarray(self._rows, dtype=float)
        self._writer.append_block(t, values)  # copies into the writer's buffer
        del t, values  # release the views before the buffers are replaced
        self._writer.flush()
        self._t, self._flat, self._rows = array("d"), array("d"), []

    def _to_rows(self) -> None:
        """Keep this flush's rows as tuples from now on (a value that is not a plain number was logged)."""
        k = len(self._keys)
        flat = self._flat.tolist()
        self._rows = [tuple(flat[i : i + k]) for i in range(0, len(flat), k)]
        self._flat = None

    def close(self) -> None:
        self.flush()
        if self._writer is not None:
            self._writer.close()
