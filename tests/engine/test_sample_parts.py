"""StoreSamples.write_parts stores exactly what write stores for the merged sample, whatever the parts do."""

import numpy as np
import pytest

from studyctl.engine.sample_buffer import StoreSamples
from studyctl.errors import SessionError


class _Writer:
    def __init__(self, keys):
        self.keys, self.t, self.rows = keys, [], []

    def append_block(self, t, values):
        self.t.extend(np.asarray(t).tolist())
        self.rows.extend(np.asarray(values, dtype=object).tolist())

    def flush(self):
        pass

    def close(self):
        pass


class _Store:
    def sample_writer(self, trial, keys, **kw):
        self.writer = _Writer(keys)
        return self.writer


def _stored(ticks, parts: bool):
    store = _Store()
    sink = StoreSamples(store, 1)
    for t, (a, b, c) in enumerate(ticks):
        if parts:
            sink.write_parts(float(t), a, b, c)
        else:
            sink.write(float(t), {**a, **b, **c})
    sink.close()
    return store.writer.keys, store.writer.t, store.writer.rows


def _same(ticks):
    assert repr(_stored(ticks, True)) == repr(_stored(ticks, False))  # repr: NaN equals itself


def test_parts_equal_merged_sample_with_fixed_channels():
    _same([({"x": 1.0 * i, "y": 2.0}, {"f": 0.5 * i}, {}) for i in range(5)])
    _same([({"x": 1.0}, {}, {"d": 3.0 + i, "e": 1.0}) for i in range(3)])


def test_parts_that_overlap_or_change_keys_still_give_the_merged_sample():
    # later parts win on a shared channel, as in {**a, **b, **c}
    _same([({"x": 1.0, "f": 9.0}, {"f": float(i)}, {"x": -1.0}) for i in range(4)])
    # a channel moves from one part to another with the same lengths: the merged value must be stored
    _same([({"x": 1.0, "y": 2.0}, {"f": 0.0}, {"d": 1.0}),
           ({"x": 1.0, "f": 7.0}, {"y": 5.0}, {"d": 1.0}),
           ({"x": 3.0, "y": 2.0}, {"f": 0.0}, {"d": 1.0, "extra": 4.0})])
    # key order inside a part changes
    _same([({"x": 1.0, "y": 2.0}, {}, {}), ({"y": 4.0, "x": 3.0}, {}, {})])
    # a value that is not a float switches to object rows the same way
    _same([({"x": 1.0}, {"s": 2.0}, {}), ({"x": 1.0}, {"s": None}, {})])


def test_parts_missing_a_channel_raise_as_write_does():
    sink = StoreSamples(_Store(), 1)
    sink.write_parts(0.0, {"x": 1.0}, {"f": 0.0}, {})
    with pytest.raises(SessionError, match="lacks channel 'f'"):
        sink.write_parts(0.1, {"x": 1.0}, {"g": 0.0}, {})
