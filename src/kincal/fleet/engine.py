"""Where the fleet's tasks run: in this process, or on Dask distributed.

* :class:`SerialEngine` - a plain loop in this process (no Dask needed);
* :class:`DaskEngine` - Dask distributed: an embedded ``LocalCluster`` of worker
  processes (one thread each; by default one per core), or an existing cluster by its
  scheduler address (``tcp://HOST:PORT``).

Both give :meth:`~SerialEngine.map_unordered` (results as they finish, each with the
index of its input and the exception that stopped it, if any: one failed task never
stops the others) and :meth:`~SerialEngine.map` (results in input order, for heavy
single-robot work such as cross-validation folds: the ``mapper`` those functions take).

A task whose worker process dies is re-run on another worker by the scheduler; after
``distributed.scheduler.allowed-failures`` deaths (3) it comes back as a
``KilledWorker`` exception for that task alone.  Tasks are submitted in a moving window
(a few per worker thread ahead), so the client's and the scheduler's memory stay
bounded for any fleet size.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from kincal.errors import KincalError

__all__ = ["SerialEngine", "DaskEngine", "make_engine", "machine_cores", "describe_failure"]

Outcome = tuple[int, Any, BaseException | None]


def machine_cores() -> int:
    """Cores this process may use (the CPU affinity set where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:                       # macOS, Windows
        return max(1, os.cpu_count() or 1)


def describe_failure(exc: BaseException) -> str:
    """One line for a task that raised instead of returning a record."""
    name = type(exc).__name__
    if name == "KilledWorker":
        return ("the worker process died every time it ran this task (out of memory or "
                "killed?): KilledWorker")
    if name in ("CancelledError", "FutureCancelledError"):
        return "the task was cancelled (the scheduler or the cluster went away)"
    text = str(exc).replace("\n", " ")
    return f"{name}: {text}" if text else name


def _check_reachable(address: str) -> None:
    """A one-line error at once when nothing listens at ``tcp://HOST:PORT`` (the Dask
    client would retry a refused connection until its timeout)."""
    import socket
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(address if "://" in address else f"tcp://{address}")
        host, port = parts.hostname, parts.port
    except ValueError:
        host = port = None
    if parts.scheme not in ("tcp", "tls") or not host or not port:
        raise KincalError(f"option --scheduler: {address!r} is not tcp://HOST:PORT")
    try:
        socket.create_connection((host, port), timeout=10).close()
    except OSError as exc:
        raise KincalError(f"option --scheduler: cannot reach a Dask scheduler at {address} "
                          f"({exc.strerror or exc})") from None


class SerialEngine:
    """Run tasks one after the other in this process."""

    name = "serial"

    def __init__(self) -> None:
        self.workers = 1
        self.threads = 1

    def map_unordered(self, fn: Callable[[Any], Any], items: Iterable[Any]
                      ) -> Iterator[Outcome]:
        """``(index, fn(item), None)`` per item, or ``(index, None, exception)``."""
        for i, item in enumerate(items):
            try:
                yield i, fn(item), None
            except Exception as exc:                  # noqa: BLE001 - reported per task
                yield i, None, exc

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        """``[fn(item) ...]`` in order; the first exception is raised."""
        return [fn(x) for x in items]

    def describe(self) -> str:
        return "in this process (serial)"

    def close(self) -> None:
        return None

    def __enter__(self) -> SerialEngine:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class DaskEngine:
    """Dask distributed: an embedded ``LocalCluster`` or an existing scheduler.

    Args:
        scheduler: ``tcp://HOST:PORT`` of a running scheduler (``dask scheduler``), or
            None for an embedded ``LocalCluster``.
        workers: worker processes of the embedded cluster (default: one per core).
        window: tasks in flight at once (default: 8 per worker thread, at least 16).
        timeout: seconds to wait for the scheduler.
    """

    name = "dask"

    def __init__(self, scheduler: str | None = None, workers: int | None = None,
                 window: int | None = None, timeout: float = 30.0) -> None:
        try:
            import distributed  # noqa: F401
        except ImportError:
            raise KincalError("the fleet engine needs Dask distributed: pip install "
                              "'kincal[fleet]'") from None
        if scheduler and workers is not None:
            raise KincalError("give either --scheduler or --workers: the workers of an "
                              "existing cluster are started with it")
        if workers is not None and workers < 1:
            raise KincalError(f"option --workers: needs at least 1 (got {workers})")
        self.scheduler = scheduler
        self.timeout = timeout
        self.cluster: Any = None
        self.client: Any = None
        self.workers = workers if workers is not None else machine_cores()
        self.threads = self.workers
        self._window = window

    def start(self) -> DaskEngine:
        """Start the embedded cluster or connect to the scheduler (done by the first
        map; a run with nothing to compute never starts a cluster)."""
        if self.client is not None:
            return self
        # distributed carries no annotations: the no-untyped-call ignores here are that gap.
        from distributed import Client, LocalCluster

        quiet = logging.ERROR
        for name in ("distributed", "distributed.nanny", "distributed.scheduler",
                     "distributed.worker", "distributed.core", "tornado"):
            logging.getLogger(name).setLevel(quiet)
        if self.scheduler:
            _check_reachable(self.scheduler)
            try:
                self.client = Client(  # type: ignore[no-untyped-call]
                    self.scheduler, timeout=self.timeout, set_as_default=False)
            except (OSError, TimeoutError) as exc:
                raise KincalError(f"option --scheduler: cannot reach a Dask scheduler at "
                                  f"{self.scheduler} ({type(exc).__name__}: {exc})") from None
        else:
            self.cluster = LocalCluster(  # type: ignore[no-untyped-call]
                n_workers=self.workers, threads_per_worker=1, processes=True,
                dashboard_address=None, silence_logs=quiet, host="127.0.0.1")
            self.client = Client(self.cluster,  # type: ignore[no-untyped-call]
                                 set_as_default=False)
        info = self.client.scheduler_info()
        self.workers = len(info["workers"])
        self.threads = sum(w.get("nthreads", 1) for w in info["workers"].values()) or 1
        return self

    @property
    def window(self) -> int:
        return self._window or max(16, 8 * self.threads)

    def describe(self) -> str:
        if self.scheduler:
            return f"Dask distributed (scheduler {self.scheduler})"
        return f"Dask distributed (embedded LocalCluster, {self.workers} worker process(es))"

    def map_unordered(self, fn: Callable[[Any], Any], items: Iterable[Any]
                      ) -> Iterator[Outcome]:
        """Submit ``fn(item)`` for every item (a window at a time); yield ``(index,
        result, None)`` or ``(index, None, exception)`` as each finishes."""
        from distributed import as_completed

        self.start()
        it = enumerate(items)
        pending: dict[str, int] = {}
        done = as_completed(loop=self.client.loop)  # type: ignore[no-untyped-call]
        exhausted = False

        def refill() -> None:
            nonlocal exhausted
            batch: list[tuple[int, Any]] = []
            while not exhausted and len(pending) + len(batch) < self.window:
                try:
                    batch.append(next(it))
                except StopIteration:
                    exhausted = True
            if batch:
                futures = self.client.map(fn, [x for _, x in batch], pure=False)
                for (i, _), f in zip(batch, futures, strict=True):
                    pending[f.key] = i
                    done.add(f)  # type: ignore[no-untyped-call]

        refill()
        for f in done:
            i = pending.pop(f.key)
            try:
                yield i, f.result(), None
            except Exception as exc:                  # noqa: BLE001 - reported per task
                yield i, None, exc
            finally:
                f.release()
            if len(pending) <= self.window // 2:
                refill()

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        """``[fn(item) ...]`` in input order, computed on the cluster; the first
        exception is raised."""
        items = list(items)
        out: list[Any] = [None] * len(items)
        for i, r, exc in self.map_unordered(fn, items):
            if exc is not None:
                raise exc
            out[i] = r
        return out

    def worker_pids(self) -> dict[str, int]:
        """``{worker address: process id}`` (tests kill one)."""
        pids: dict[str, int] = self.start().client.run(os.getpid)
        return pids

    def close(self) -> None:
        try:
            if self.client is not None:
                self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()
            self.client = self.cluster = None

    def __enter__(self) -> DaskEngine:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def make_engine(scheduler: str | None = None, workers: int | None = None,
                serial: bool = False) -> SerialEngine | DaskEngine:
    """The engine a command asked for: ``serial`` (in-process), ``scheduler`` (an
    existing cluster) or an embedded ``LocalCluster`` of ``workers`` processes."""
    if serial:
        if scheduler or workers is not None:
            raise KincalError("--serial runs in this process: drop --scheduler / --workers")
        return SerialEngine()
    return DaskEngine(scheduler=scheduler, workers=workers)

