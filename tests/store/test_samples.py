"""High-rate samples: exact round trip, chunking by flush interval, streams, resumption, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from studyctl.errors import NotFoundError, UsageError
from studyctl.store.samples import SampleWriter


@pytest.fixture
def trial(store):
    study = store.create_study("s")
    p = store.add_participant(study.id, "P1")
    sess = store.start_session(p.id)
    return store.add_trial(sess.id, plan_position=0, condition="c")


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_block_round_trip_is_exact(store, trial):
    rng = np.random.default_rng(1)
    t = np.arange(5000) / 1000.0
    v = rng.normal(size=(5000, 16)) * 1e3
    v[7, 3] = np.finfo(float).tiny
    v[8, 4] = -0.0
    names = [f"ch{i}" for i in range(16)]
    with store.sample_writer(trial.id, names) as w:
        for i in range(0, 5000, 250):
            w.append_block(t[i : i + 250], v[i : i + 250])
    assert w.rows_written == 5000 and w.chunks_written == 5  # one chunk per second of samples
    df = store.read_samples(trial.id)
    assert list(df.columns) == ["t", *names]
    np.testing.assert_array_equal(df["t"].to_numpy(), t)
    np.testing.assert_array_equal(df[names].to_numpy(), v)
    assert np.signbit(df["ch4"][8])


def test_row_appends_with_mappings_and_fake_clock(store, trial):
    clock = FakeClock()
    w = store.sample_writer(trial.id, flush_interval_s=1.0, clock=clock)
    for i in range(10):
        clock.now = i * 0.3  # wall time runs faster than sample time here
        w.append(i * 0.01, {"force": float(i), "depth": -float(i)})
    # Flushed whenever 1 s of wall time passed since the last flush: after rows 4 (t=1.2) and 8 (t=2.4).
    assert w.chunks_written == 2 and w.buffered == 1
    clock.now = 2.9
    w.poll()  # not yet a second since the last flush
    assert w.buffered == 1
    clock.now = 3.5
    w.poll()  # idle loop: the last row is committed without a new sample arriving
    assert w.buffered == 0 and w.chunks_written == 3
    w.close()
    df = store.read_samples(trial.id)
    assert list(df.columns) == ["t", "force", "depth"]
    assert df["force"].tolist() == [float(i) for i in range(10)]
    with pytest.raises(UsageError, match="closed"):
        w.append(1.0, {"force": 1.0, "depth": 1.0})


def test_float32_streams_and_several_streams(store, trial):
    with SampleWriter(store.db, trial.id, ["x"], stream="gaze", dtype="<f4") as w:
        w.append_block([0.0, 0.5], [[1.1], [2.2]])
    with SampleWriter(store.db, trial.id, ["a", "b"], stream="device") as w:
        w.append(0.0, [1.0, 2.0])
    assert store.sample_streams(trial.id) == ["device", "gaze"]
    gaze = store.read_samples(trial.id, "gaze")
    assert gaze["x"].dtype == np.float64
    np.testing.assert_array_equal(gaze["x"].to_numpy(), np.array([1.1, 2.2], dtype=np.float32).astype(float))
    assert store.read_samples(trial.id, "device").shape == (1, 3)


def test_a_resumed_writer_continues_the_stream(store, trial):
    with store.sample_writer(trial.id, ["a"]) as w:
        w.append_block([0.0, 0.1], [[1.0], [2.0]])
    with store.sample_writer(trial.id) as w:  # channels taken from the stored stream
        w.append(0.2, [3.0])
    assert store.read_samples(trial.id)["a"].tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(UsageError, match="already stores channels"):
        store.sample_writer(trial.id, ["b"])


def test_empty_stream_reads_as_empty_frame(store, trial):
    df = store.read_samples(trial.id)
    assert list(df.columns) == ["t"] and len(df) == 0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"dtype": "<i4"}, "dtype"), ({"flush_interval_s": 0}, "flush_interval_s"), ({"stream": ""}, "stream")],
)
@pytest.mark.slow
def test_bad_writer_settings(store, trial, kwargs, match):
    with pytest.raises(UsageError, match=match):
        store.sample_writer(trial.id, ["a"], **kwargs)


def test_bad_rows_are_refused(store, trial):
    w = store.sample_writer(trial.id, ["a", "b"])
    with pytest.raises(UsageError, match="has 3 values; expected 2"):
        w.append(0.0, [1.0, 2.0, 3.0])
    with pytest.raises(UsageError, match="lacks channel 'b'"):
        w.append(0.0, {"a": 1.0})
    with pytest.raises(UsageError, match="do not match"):
        w.append_block([0.0, 1.0], [[1.0, 2.0]])
    with pytest.raises(UsageError, match="reserved"):
        store.sample_writer(trial.id, ["t", "x"], stream="other")
    with pytest.raises(UsageError, match="duplicate"):
        store.sample_writer(trial.id, ["x", "x"], stream="other")
    with pytest.raises(NotFoundError, match="no trial"):
        store.sample_writer(987654, ["a"])
