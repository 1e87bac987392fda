"""Benchmarks behind ``studyctl bench NAME``.

Each benchmark is a module ``studyctl.bench.<name>`` with a function
``run(quick: bool = False) -> BenchResult``. Timing lives here, never in unit tests.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from studyctl.errors import NotFoundError, UsageError


@dataclass(frozen=True)
class BenchResult:
    """Figures of one benchmark run.

    ``figures`` are the named numbers outside checks parse; ``peers`` the same figures measured for a
    peer library in the same run; ``tables`` extra rows (e.g. speed against error variants);
    ``notes`` say what was measured and how.
    """

    name: str
    figures: dict[str, float]
    peers: dict[str, float] = field(default_factory=dict)
    tables: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {
            "benchmark": self.name,
            "figures": self.figures,
            "peers": self.peers,
            "tables": self.tables,
            "notes": self.notes,
        }


def available() -> list[str]:
    """Names of the benchmarks in this installation."""
    import studyctl.bench as pkg

    return sorted(m.name for m in pkgutil.iter_modules(pkg.__path__) if not m.name.startswith("_"))


def load(name: str) -> Callable[..., BenchResult]:
    """The ``run`` function of benchmark ``name``."""
    if name not in available():
        raise NotFoundError(f"unknown benchmark {name!r}; available: {', '.join(available())}")
    return importlib.import_module(f"studyctl.bench.{name}").run


def worker_options(name: str, workers: int | None) -> dict[str, int]:
    """``run``'s keyword for ``--workers``: only benchmarks that start a cluster take it, and bad values are refused
    here, before a benchmark starts its minutes of work."""
    if workers is None:
        return {}
    if "workers" not in inspect.signature(load(name)).parameters:
        takes = sorted(n for n in available() if "workers" in inspect.signature(load(n)).parameters)
        raise UsageError(f"--workers {workers}: benchmark {name!r} starts no cluster; only {', '.join(takes)} take "
                         "--workers (drop the option)")
    if workers < 1:
        raise UsageError(f"--workers {workers}: a cluster needs at least 1 worker; use --workers 1 to run serially "
                         "without a cluster")
    return {"workers": workers}


def time_calls(fn: Callable[[], object], repeat: int, warmup: int = 3) -> np.ndarray:
    """Wall time in seconds of ``repeat`` calls of ``fn`` (after ``warmup`` untimed calls)."""
    for _ in range(warmup):
        fn()
    out = np.empty(repeat)
    clock = time.perf_counter
    for i in range(repeat):
        t0 = clock()
        fn()
        out[i] = clock() - t0
    return out


def busy_python(stop: Any) -> None:
    """Stand-in for a coordinator's UI/logging thread: pure-Python work that wants the interpreter lock until
    ``stop`` (a threading.Event) is set."""
    x = 0
    while not stop.is_set():
        for i in range(2000):
            x += i * i
        x %= 1_000_003
