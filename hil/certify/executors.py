"""Executors of the sweep's tasks (a registry, :data:`EXECUTORS`: name -> factory): ``serial`` (in this
process, the reference every executor must match), ``process`` (a local process pool, the default) and
``dask`` (a distributed scheduler, extra ``dask``). Each runs ``fn(*task)`` for every task and yields
``(index, result)`` as they finish; a lost pool or scheduler is :class:`ExecutorLost` (one line).
Used by :func:`hil.certify.sweep.run_sweep` and :mod:`hil.certify.fleet`; re-exported there."""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["EXECUTORS", "DaskExecutor", "Executor", "ExecutorLost", "ProcessExecutor", "SerialExecutor", "SweepError",
           "make_executor"]


class SweepError(HilError, ValueError):
    """A sweep that cannot be set up (bad grid, unknown parameter, missing extra) or whose executor
    cannot run it."""


class Executor:
    """Runs tasks and yields ``(index, result)`` as they finish. Subclasses implement :meth:`submit_all`."""

    name = "base"

    def map_unordered(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        raise NotImplementedError

    def close(self) -> None:
        """Release workers (idempotent)."""


class SerialExecutor(Executor):
    """In this process, one task after the other (the reference every executor must match)."""

    name = "serial"

    def map_unordered(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        for i, t in enumerate(tasks):
            yield i, fn(*t)


def _ignore_sigint() -> None:
    """Workers leave SIGINT to the parent (a Ctrl-C reaches the whole process group): the parent
    stops handing out tasks at the next safe point and keeps every finished one."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


class ProcessExecutor(Executor):
    """A local process pool (``workers`` processes, default all cores)."""

    name = "process"

    def __init__(self, workers: int | None = None) -> None:
        self.workers = workers or os.cpu_count() or 1
        self._pool: ProcessPoolExecutor | None = None

    def map_unordered(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        """At most ``workers`` tasks in flight: a task is handed out only after the consumer took
        the previous result, so a consumer that stops (a signal) starts nothing new."""
        from concurrent.futures import FIRST_COMPLETED, wait

        if self._pool is None:
            import multiprocessing as mp

            self._pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"),
                                             initializer=_ignore_sigint)
        todo = iter(enumerate(tasks))
        pending: dict[Any, int] = {}

        def fill() -> None:
            assert self._pool is not None
            for i, t in todo:
                pending[self._pool.submit(fn, *t)] = i
                if len(pending) >= self.workers:
                    return

        fill()
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for f in done:
                    i = pending.pop(f)
                    yield i, f.result()
                fill()
        finally:
            for f in pending:
                f.cancel()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class ExecutorLost(SweepError):
    """The executor's workers or its scheduler are gone: the tasks not finished cannot run. The
    finished ones were handed to the caller (and cached), so a rerun resumes (one-line message)."""


class DaskExecutor(Executor):
    """Dask distributed: ``scheduler`` is an address (``tcp://host:8786``) or a ``distributed.Client``
    (tests pass one on an in-process LocalCluster). Extra ``dask``.

    Lost workers and a lost scheduler end the map in a bounded time with :class:`ExecutorLost`
    (issue 27): while tasks are pending the scheduler is asked every ``poll_s`` s how many workers
    it has; none for ``no_worker_timeout_s`` s (a warning is logged when they go) ends it, and so
    does a scheduler the client cannot reach for ``scheduler_timeout_s`` s or that cancels the
    tasks (killed, restarted). A task's own
    exception is raised as it is. The long-lived workers' memory is released after each map (see
    :func:`_release_worker_memory`)."""

    name = "dask"
    #: seconds between checks of the cluster while tasks are pending
    poll_s = 1.0
    #: how long pending tasks wait for a worker when the scheduler has none (s)
    no_worker_timeout_s = 60.0
    #: how long pending tasks wait for a scheduler that stopped answering (s)
    scheduler_timeout_s = 10.0

    def __init__(self, scheduler: Any = None, workers: int | None = None) -> None:
        try:
            import distributed
        except ImportError:
            raise SweepError("the dask executor needs dask.distributed: pip install 'hil-certify[dask]'") from None
        self._own = False
        if isinstance(scheduler, distributed.Client):
            self.client = scheduler
        elif scheduler:
            try:
                self.client = distributed.Client(scheduler, timeout="10s")
            except OSError as exc:
                raise SweepError(f"--scheduler {scheduler}: cannot connect: {exc}") from None
            self._own = True
        else:
            import dask

            with dask.config.set({"distributed.worker.profile.enabled": False}):  # its history grows per second
                cluster = distributed.LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                                                   processes=True, dashboard_address=None)
            self.client = distributed.Client(cluster)
            self._own = True
        self._gone = False  # the scheduler was lost: nothing more is asked of it
        given = scheduler if isinstance(scheduler, str) else None
        self.address = str(getattr(getattr(self.client, "scheduler", None), "address", None) or given
                           or "the local cluster")

    def _lost(self, why: str) -> ExecutorLost:
        return ExecutorLost(f"the Dask scheduler at {self.address} {why}")

    def _workers(self) -> int:
        """Workers the scheduler has now (asks it); :class:`ExecutorLost` when it does not answer."""
        try:
            return len(self.client.nthreads())
        except Exception as exc:  # CommClosedError, OSError, TimeoutError, a closed client
            self._gone = True
            raise self._lost(f"does not answer ({type(exc).__name__}: {' '.join(str(exc).split()) or 'closed'})"
                             ) from None

    def map_unordered(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        """At most two tasks per worker thread in flight (a stopped consumer starts little new)."""
        from distributed import wait as dask_wait

        limit = max(1, 2 * sum(self.client.nthreads().values()))
        todo = iter(enumerate(tasks))
        index: dict[Any, int] = {}  # future key -> task index
        live: dict[Any, Any] = {}  # future key -> future not yet consumed

        def submit() -> bool:
            for i, t in todo:
                f = self.client.submit(fn, *t, pure=False)
                index[f.key] = i
                live[f.key] = f
                return True
            return False

        while len(live) < limit and submit():
            pass
        no_workers_since: float | None = None
        unreachable_since: float | None = None
        try:
            while live:
                try:
                    done, _ = dask_wait(list(live.values()), timeout=self.poll_s, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    done = set()
                except Exception as exc:  # the connection to the scheduler failed: the tasks were cancelled
                    self._gone = True
                    what = ("the client lost its connection" if "cancel" in type(exc).__name__.lower()
                            else f"{type(exc).__name__}: {' '.join(str(exc).split())}")
                    raise self._lost(f"is gone ({what}; {len(live)} tasks not finished)") from None
                if not done:
                    now = time.monotonic()
                    status = str(getattr(self.client, "status", "running"))
                    if status != "running":  # the connection to the scheduler is lost: it reconnects
                        unreachable_since = unreachable_since or now
                        if now - unreachable_since > self.scheduler_timeout_s:
                            self._gone = True
                            raise self._lost(f"does not answer (unreachable for {self.scheduler_timeout_s:g} s, "
                                             f"client {status})")
                        continue
                    unreachable_since = None
                    n = self._workers()
                    if n:
                        no_workers_since = None
                    elif no_workers_since is None:
                        no_workers_since = now
                        logger.warning("the Dask scheduler at %s has no worker left: %d tasks wait (at most %g s)",
                                       self.address, len(live), self.no_worker_timeout_s)
                    elif now - no_workers_since > self.no_worker_timeout_s:
                        raise self._lost(f"has had no worker for {self.no_worker_timeout_s:g} s ({len(live)} tasks "
                                         "waiting): start workers, or rerun")
                    continue
                for f in done:
                    live.pop(f.key, None)
                    if f.status == "error":
                        err = f.exception()
                        if type(err).__name__ == "KilledWorker":  # every worker that took it died
                            raise self._lost(f"lost task {index[f.key]}: {' '.join(str(err).split())}") from None
                        f.result()  # the task's own exception, raised as it is
                    try:
                        res = f.result()
                    except Exception as exc:  # cancelled: the client lost the scheduler (killed, restarted)
                        self._gone = True
                        raise self._lost(f"is gone: task {index[f.key]} was cancelled ({type(exc).__name__}"
                                         f"{': ' if str(exc).strip() else ''}{' '.join(str(exc).split())})") from None
                    yield index[f.key], res
                    submit()
        finally:
            if not self._gone:  # (a client without its scheduler would wait for it to come back)
                if live:
                    with contextlib.suppress(Exception):
                        self.client.cancel(list(live.values()))
                _release_worker_memory(self.client)

    def close(self) -> None:
        if self._own:
            cluster = getattr(self.client, "cluster", None)
            quiet = logging.getLogger("distributed.client")
            level = quiet.level
            if self._gone:  # closing stops its reconnection loop, which logs that as a traceback
                quiet.setLevel(logging.CRITICAL + 1)
            try:
                with contextlib.suppress(Exception):
                    self.client.close(timeout=2 if self._gone else None)  # (gone: it would wait to reconnect)
            finally:
                quiet.setLevel(level)
            if cluster is not None:
                with contextlib.suppress(Exception):
                    cluster.close()
            self._own = False


def _trim_memory(dask_worker: Any = None) -> int:  # pragma: no cover - runs on the workers
    """On a worker: forget what grows with every task and every second of work -- the statistical
    profiler's history (one call tree per profile cycle, kept for an hour) and the developer logs of
    each task's events -- then collect garbage and give freed heap back to the system (glibc
    ``malloc_trim``). Returns the worker's RSS [bytes]."""
    import ctypes
    import gc

    if dask_worker is not None:
        state = getattr(dask_worker, "state", None)
        for log in (getattr(dask_worker, "profile_history", None), getattr(dask_worker, "profile_keys_history", None),
                    getattr(dask_worker, "profile_keys", None), getattr(state, "stimulus_log", None),
                    getattr(state, "log", None)):
            if log is not None:
                log.clear()
        with contextlib.suppress(Exception):
            from distributed import profile

            dask_worker.profile_recent = profile.create()
    gc.collect()
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    try:  # resident pages (Linux); -1 elsewhere
        with open("/proc/self/statm", encoding="ascii") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return -1


def _release_worker_memory(client: Any) -> None:
    """After a map: :func:`_trim_memory` on every worker (long-lived workers otherwise keep growing
    from one sweep to the next: docs/BENCHMARKS.md "Dask worker memory"). Never raises."""
    with contextlib.suppress(Exception):
        client.run(_trim_memory)


EXECUTORS: dict[str, Callable[..., Executor]] = {
    "serial": lambda workers=None, scheduler=None: SerialExecutor(),
    "process": lambda workers=None, scheduler=None: ProcessExecutor(workers),
    "dask": lambda workers=None, scheduler=None: DaskExecutor(scheduler, workers),
}


def make_executor(name: str, workers: int | None = None, scheduler: Any = None) -> Executor:
    """An executor from :data:`EXECUTORS` by name (``--executor``)."""
    try:
        factory = EXECUTORS[name]
    except KeyError:
        raise SweepError(f"--executor {name}: unknown; known: {', '.join(EXECUTORS)}") from None
    return factory(workers=workers, scheduler=scheduler)
