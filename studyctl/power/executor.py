"""Where replicates run: serially in this process, on a local Dask cluster of worker processes, or on an
existing Dask distributed scheduler.

Every replicate is an independent task ``simulate_replicate(spec, n, r)`` whose result depends only on
its arguments, so the backend changes how fast results arrive, never what they are. Connecting (and
checking that the workers can run studyctl) happens when a backend is opened, before any work starts.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from studyctl import __version__
from studyctl.errors import StudyctlError, UsageError
from studyctl.plugins import registry
from studyctl.power.replicate import ReplicateResult, WorkerMemoryError, simulate_replicate
from studyctl.power.spec import PowerSpec

CONNECT_TIMEOUT_S = 10.0
ResultFn = Callable[[ReplicateResult], None]


@dataclass
class BackendInfo:
    """What ran the replicates (for the report): kind, address, workers and their memory caps."""

    kind: str  # "serial", "local", "scheduler"
    address: str = ""
    workers: int = 1
    memory_limit: int | None = None
    worker_memory_limits: list[int | None] = field(default_factory=list)

    def describe(self) -> str:
        cap = "no memory cap" if self.memory_limit is None else f"memory cap {self.memory_limit / 2**30:.2f} GiB/worker"
        if self.kind == "serial":
            return f"serial, in this process ({cap})"
        where = "local Dask cluster" if self.kind == "local" else "Dask scheduler"
        return f"{where} {self.address}, {self.workers} worker(s) ({cap})"


class SerialBackend:
    """Replicates one after another in this process (``--workers 0``)."""

    def __init__(self, memory_limit: int | None) -> None:
        self.info = BackendInfo("serial", memory_limit=memory_limit)

    def close(self) -> None:
        return None

    def abort(self) -> None:
        return None

    def run(self, spec: PowerSpec, tasks: Iterable[tuple[int, int]], on_result: ResultFn) -> None:
        self.map(simulate_replicate, spec, tasks, on_result)

    def map(self, fn: Callable[..., Any], spec: PowerSpec, tasks: Iterable[tuple[Any, ...]],
            on_result: Callable[[Any], None], tag: str = "") -> None:
        """``on_result(fn(spec, *args))`` for every args tuple of ``tasks``, in order."""
        for args in tasks:
            on_result(fn(spec, *args))


def _worker_report() -> dict[str, Any]:
    """Run on each worker: can it run studyctl's simulations, and which version is it?"""
    import studyctl

    return {"version": studyctl.__version__, "participants": registry.known_names("participant")}


class DaskBackend:
    """Replicates as Dask tasks on a local cluster (processes on loopback) or an existing scheduler."""

    def __init__(self, client: Any, cluster: Any, info: BackendInfo) -> None:
        self.client = client
        self.cluster = cluster
        self.info = info

    @classmethod
    def local(cls, workers: int, memory_limit: int | None) -> DaskBackend:
        """Start a LocalCluster of ``workers`` single-threaded worker processes on 127.0.0.1."""
        LocalCluster, Client = _distributed("LocalCluster", "Client")  # noqa: N806 - class names
        import dask

        # The workers' statistical profiler samples every thread's stack 100 times a second; a replicate is
        # pure Python for minutes, so it would only take GIL time from it (nannies hand this config on).
        with dask.config.set({"distributed.worker.profile.enabled": False}), warnings.catch_warnings():
            # No dashboard is started; the scheduler's small HTTP server falls back to a free port by itself.
            warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
            cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                memory_limit=memory_limit or 0,
                dashboard_address=None,
                silence_logs=logging.ERROR,
            )
        try:
            client = Client(cluster, timeout=CONNECT_TIMEOUT_S * 3)
            client.wait_for_workers(workers, timeout=120)
        except BaseException:
            cluster.close()
            raise
        info = BackendInfo("local", cluster.scheduler_address, workers, memory_limit, [memory_limit] * workers)
        backend = cls(client, cluster, info)
        backend._check_workers()
        return backend

    @classmethod
    def connect(cls, address: str, workers: int, memory_limit: int | None) -> DaskBackend:
        """Connect to the scheduler at ``address`` and wait (up to 10 s) for ``workers`` workers.

        The workers' own memory limits are theirs (``dask worker --memory-limit``); ``memory_limit`` is
        also checked inside every replicate against the worker process's resident memory.
        """
        (Client,) = _distributed("Client")  # noqa: N806 - class name
        target = address if "://" in address else f"tcp://{address}"
        _probe(address, target)
        try:
            client = Client(target, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise UsageError(
                f"cannot reach the Dask scheduler at {address} within {CONNECT_TIMEOUT_S:g} s "
                f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__}); start one with "
                f"`dask scheduler` and workers with `dask worker {target}`, or omit --scheduler to use a "
                "local cluster"
            ) from None
        try:
            try:
                client.wait_for_workers(max(workers, 1), timeout=CONNECT_TIMEOUT_S)
            except (TimeoutError, OSError):
                have = len(client.scheduler_info().get("workers", {}))
                raise UsageError(
                    f"the Dask scheduler at {address} has {have} worker(s), fewer than --workers "
                    f"{max(workers, 1)} after {CONNECT_TIMEOUT_S:g} s; start workers with "
                    f"`dask worker {target}`"
                ) from None
            found = client.scheduler_info().get("workers", {})
            limits = [w.get("memory_limit") or None for w in found.values()]
            info = BackendInfo("scheduler", target, len(found), memory_limit, limits)
            backend = cls(client, None, info)
            backend._check_workers()
        except BaseException:
            client.close()
            raise
        return backend

    def _check_workers(self) -> None:
        try:
            reports = self.client.run(_worker_report)
        except Exception as exc:  # a worker without studyctl raises ModuleNotFoundError remotely
            raise UsageError(
                f"the Dask workers at {self.info.address} cannot run studyctl ({type(exc).__name__}: "
                f"{exc}); install the same studyctl ({__version__}) in the workers' environment"
            ) from None
        for addr, rep in reports.items():
            if rep.get("version") != __version__:
                raise UsageError(
                    f"Dask worker {addr} runs studyctl {rep.get('version')}, this is {__version__}; "
                    "results would not be comparable: install the same version on every worker"
                )

    def abort(self) -> None:
        """Stop at once (Ctrl-C): a local cluster's worker processes are this process's children, killed rather
        than asked to finish the task they are in (a pool chunk or replicate can take minutes under load; what
        they were computing is not kept, everything committed before is)."""
        if self.cluster is not None:
            import multiprocessing

            for child in multiprocessing.active_children():
                with contextlib.suppress(Exception):
                    child.kill()
        with contextlib.suppress(Exception):
            self.client.close(timeout=2)
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close(timeout=2)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.client.close()
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close()

    def run(self, spec: PowerSpec, tasks: Iterable[tuple[int, int]], on_result: ResultFn) -> None:
        self.map(simulate_replicate, spec, tasks, on_result, tag="replicate")

    def map(self, fn: Callable[..., Any], spec: PowerSpec, tasks: Iterable[tuple[Any, ...]],
            on_result: Callable[[Any], None], tag: str = "") -> None:
        """``fn(spec, *args)`` as one Dask task per args tuple; ``on_result`` as each finishes (any order)."""
        (as_completed,) = _distributed("as_completed")
        tasks = list(tasks)
        if not tasks:
            return
        digest = hashlib.sha256(repr(sorted(spec.fingerprint().items())).encode()).hexdigest()[:12]
        shared = self.client.scatter(spec, broadcast=True, hash=False)
        futures = [
            self.client.submit(fn, shared, *args, key=f"studyctl-power-{tag}-{digest}-{'-'.join(map(str, args))}",
                               pure=False)
            for args in tasks
        ]
        try:
            for future in as_completed(futures, loop=self.client.loop):
                try:
                    result = future.result()
                except StudyctlError:
                    raise
                except Exception as exc:
                    name = type(exc).__name__
                    if name == "KilledWorker":
                        raise WorkerMemoryError(
                            f"a Dask worker died repeatedly running {future.key} (most often: over its memory "
                            f"limit, {self.info.describe()}); raise --memory-limit or use fewer participants"
                        ) from None
                    raise
                on_result(result)
                future.release()
        finally:
            self.client.cancel(futures)


def _probe(address: str, target: str) -> None:
    """Fail at once, with the reason, when nothing listens at a tcp:// address (Dask would retry until
    its timeout and then only say it timed out)."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(target)
    if parts.scheme != "tcp":
        return
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host = port = None
    if not host or not port:
        raise UsageError(f"--scheduler {address!r}: expected HOST:PORT or tcp://HOST:PORT (e.g. tcp://127.0.0.1:8786)")
    try:
        with socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise UsageError(f"cannot reach the Dask scheduler at {address} ({reason}); start one with "
                         f"`dask scheduler` and workers with `dask worker {target}`, or omit --scheduler to use a "
                         "local cluster") from None


def _distributed(*names: str) -> tuple[Any, ...]:
    try:
        import distributed
    except ImportError:
        raise UsageError(
            "running on Dask needs the distributed package: pip install 'studyctl[power]' "
            "(or use --workers 0 to run serially)"
        ) from None
    return tuple(getattr(distributed, n) for n in names)


def open_backend(scheduler: str | None, workers: int | None, memory_limit: int | None) -> SerialBackend | DaskBackend:
    """The backend for the command's options (see :func:`studyctl.power.run_power`)."""
    if workers is not None and (isinstance(workers, bool) or workers < 0):
        raise UsageError(f"--workers must be 0 (serial) or more, got {workers}")
    if scheduler:
        return DaskBackend.connect(scheduler, 1 if not workers else workers, memory_limit)
    if workers == 0:
        return SerialBackend(memory_limit)
    return DaskBackend.local(workers or (os.cpu_count() or 1), memory_limit)
