"""Worker process: log two complete trials, then a third one until it is killed.

Prints one line per durable step so the parent knows what was acknowledged:
``completed TRIAL ROWS``, ``flushed TRIAL ROWS_WRITTEN``, ``event SEQ``.
"""

import sys
import time

import numpy as np

from studyctl.store import StudyStore

RATE = 1000
BLOCK = 100  # rows per append_block
CHANNELS = [f"ch{i}" for i in range(16)]


def values(trial_index: int, start: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic samples, so the parent can check every stored value."""
    rows = np.arange(start, start + n)
    t = rows / RATE
    v = (trial_index * 1e6 + rows[:, None] * 16 + np.arange(16)[None, :]).astype(float)
    return t, v


def main() -> None:
    url, session_id = sys.argv[1], int(sys.argv[2])
    store = StudyStore.open(url)
    for index in range(3):
        trial = store.add_trial(session_id, plan_position=index, condition="linear", time_limit_s=90.0)
        store.update_trial(trial.id, status="running")
        writer = store.sample_writer(trial.id, CHANNELS, flush_interval_s=1.0)
        written = 0
        block = BLOCK
        while index < 2 and written < 2 * RATE or index == 2:
            t, v = values(index, written, block)
            before = writer.chunks_written
            writer.append_block(t, v)
            written += block
            if writer.chunks_written != before:
                print(f"flushed {trial.id} {writer.rows_written}", flush=True)
            seq = store.append_event(session_id, "tick", {"rows": written}, t_mono=written / RATE, trial_id=trial.id)
            print(f"event {seq}", flush=True)
            if index == 2:
                time.sleep(0.005)
        writer.close()
        store.update_trial(trial.id, status="completed")
        print(f"completed {trial.id} {writer.rows_written}", flush=True)


if __name__ == "__main__":
    main()
