"""``with thing:`` closes ``thing``: the one context-manager idiom of studyctl's closeable handles (databases,
stores, opened studies, result files); and the one way a child process (an emulator, a browser) is ended."""

from __future__ import annotations

import subprocess
from typing import Self


class Closeable:
    """A handle with a ``close()``; ``with`` closes it on the way out, also on an error."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def stop_process(proc: subprocess.Popen, timeout_s: float) -> None:
    """End a child process: ask it (SIGTERM), kill it when it has not ended after ``timeout_s``, and reap it."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
