"""Where independent tasks run: in this process, in local worker processes, or on a Dask cluster.

The numerical code hands independent pieces of work (the cross march's batches of trajectories, the
reference's chunks of samples, the specs of a family, the partitions of a large query) to an
*executor*, a small :mod:`concurrent.futures`-style interface:

- ``map(fn, items)``: ``fn(item)`` for every item, yielded in order as they are needed, with at most
  :attr:`Executor.window` tasks in flight (the memory of the results waiting is bounded); ``fn`` is
  sent to the workers once, not with every item;
- ``as_completed(fn, items)``: ``(index, future)`` pairs in the order the tasks finish; the future's
  ``result()`` is the value, or raises what the task raised;
- ``workers``: how many tasks run at once.

:class:`SerialExecutor` runs each task here when its result is asked for (the default: a build in
one process, as without any executor); :class:`ThreadExecutor` on threads of this process (tasks
whose time is in code that releases the GIL, such as LAPACK's factorizations, on cores left idle:
:func:`free_cores`); :class:`ProcessExecutor` in a pool of local processes (``pgd verify
--jobs``); :class:`DaskExecutor` on the workers of a Dask cluster (a ``distributed.Client``;
:mod:`pgdcli.cluster` opens one). The work is cut into the same tasks whatever runs them, and a task
computes the same floats wherever it runs (one BLAS thread in the workers, as in a build here), so
results do not depend on the executor.

On a cluster, a task's function is sent to every worker once (``Client.scatter``, broadcast) and each
task carries only its item. Faults: the scheduler runs again elsewhere a task whose worker died, and
recomputes results lost with it (the tasks are pure functions of their inputs); a task cancelled
under us (``Client.restart``) is submitted again, its function scattered again, at most
:data:`RESUBMITS` times. Either way the results are the ones an undisturbed run gives. A task that
killed :data:`ALLOWED_FAILURES` workers, or a scheduler gone away, is a
:class:`~pgdcli.errors.ClusterError`.

The executor in effect, :func:`current`, is set for a block by :func:`using`; :func:`pgdcli.solve`
sets it from its ``executor`` argument, so the layers below reach it without every signature
between them carrying it. Imports nothing of the package but its errors and its BLAS limiter (a leaf
every layer may use); its memory pages (numpy) only in a worker's first task, and Dask only inside the
methods of a DaskExecutor.
"""

from __future__ import annotations

import contextlib
import contextvars
import multiprocessing
import os
import sys
import threading
import time
from collections import OrderedDict, deque
from concurrent.futures import CancelledError, Future, ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from typing import Callable, Iterable, Iterator

from .blas import one_blas_thread
from .errors import ClusterError

__all__ = ["Executor", "SerialExecutor", "ThreadExecutor", "ProcessExecutor", "DaskExecutor", "current", "using",
           "as_executor", "free_cores", "pool_context"]

#: Times a cancelled task is submitted again.
RESUBMITS = 3
#: Workers a task may kill before the scheduler gives it up (distributed's ``allowed-failures``).
ALLOWED_FAILURES = 3
#: Functions kept scattered on the workers (the most recent ones).
SHARED = 4
#: Seconds to wait for a worker before a cancelled task is submitted again.
RESTART_TIMEOUT = 60.0


class Executor:
    """The interface (see the module docstring); subclasses implement :meth:`submit` and may do
    better than its default :meth:`map` and :meth:`as_completed`.

    Attributes
    ----------
    workers : int
        Tasks that run at once.
    finished : int
        Tasks whose result was handed out so far; ``progress(finished)`` is called after each.
    progress : callable or None
        Told the number of finished tasks (a progress bar counts them).
    """

    workers = 1
    description = "this process"

    def __init__(self) -> None:
        self.finished = 0
        self.progress: Callable[[int], None] | None = None

    @property
    def window(self) -> int:
        """Tasks in flight at most in :meth:`map`: enough to keep every worker busy while the
        caller takes the results in order."""
        return 2 * self.workers + 1

    def submit(self, fn: Callable, *args) -> Future:
        raise NotImplementedError

    def map(self, fn: Callable, items: Iterable) -> Iterator:
        """``fn(item)`` for every item, in order; at most :attr:`window` tasks in flight."""
        pending: deque = deque()  # (item, future)
        try:
            for item in items:
                pending.append((item, self.submit(fn, item)))
                if len(pending) >= self.window:
                    yield self._taken(fn, *pending.popleft())
            while pending:
                yield self._taken(fn, *pending.popleft())
        finally:
            for _, future in pending:
                future.cancel()

    def as_completed(self, fn: Callable, items: Iterable) -> Iterator[tuple[int, Future]]:
        """``(index, future)`` of ``fn(item)`` for every item, as the tasks finish."""
        futures = {self.submit(fn, item): i for i, item in enumerate(items)}
        try:
            for future in as_completed(futures):
                self._count()
                yield futures[future], future
        finally:
            for future in futures:
                future.cancel()

    def _taken(self, fn: Callable, item, future):
        """The value of ``fn(item)``, whose task is ``future``, counted as finished."""
        value = self._result(fn, item, future)
        self._count()
        return value

    def _result(self, fn: Callable, item, future):
        return future.result()

    def _count(self) -> None:
        self.finished += 1
        if self.progress is not None:
            self.progress(self.finished)

    def close(self, wait: bool = True) -> None:
        """Release the workers this executor started (none here); ``wait`` for tasks running (not after an
        error or an interrupt: they are abandoned)."""

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(wait=exc_type is None)


class SerialExecutor(Executor):
    """Every task in this process, when its result is asked for (the work of a plain loop)."""

    def submit(self, fn: Callable, *args) -> Future:
        future: Future = Future()
        try:
            future.set_result(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller by result(), as a pool does
            future.set_exception(exc)
        return future

    def map(self, fn: Callable, items: Iterable) -> Iterator:
        for item in items:
            value = fn(item)
            self._count()
            yield value

    def as_completed(self, fn: Callable, items: Iterable) -> Iterator[tuple[int, Future]]:
        for i, item in enumerate(items):
            future = self.submit(fn, item)
            self._count()
            yield i, future


def pool_context():
    """fork on Linux when this process runs no other thread (fast, no ``__main__`` guard needed in
    user scripts), else forkserver/spawn (forking a process that runs threads can deadlock)."""
    methods = multiprocessing.get_all_start_methods()
    if sys.platform.startswith("linux") and "fork" in methods and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")


class _Pooled(Executor):
    """An executor over a :mod:`concurrent.futures` pool of ``workers``, ``start()`` at the first task."""

    def __init__(self, workers: int, description: str, start: Callable) -> None:
        super().__init__()
        self.workers, self.description, self._start = workers, description, start
        self._pool = None

    def submit(self, fn: Callable, *args) -> Future:
        if self._pool is None:
            self._pool = self._start()
        return self._pool.submit(fn, *args)

    def close(self, wait: bool = True) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=wait, cancel_futures=True)
            self._pool = None


class ThreadExecutor(_Pooled):
    """``threads`` threads of this process, for tasks whose time is in code that releases the GIL (one
    BLAS thread each). Each task computes what it would compute alone."""

    def __init__(self, threads: int) -> None:
        workers = max(1, int(threads))
        super().__init__(workers, f"{workers} threads",
                         lambda: ThreadPoolExecutor(max_workers=workers, thread_name_prefix="pgdcli"))


def free_cores() -> int:
    """Cores this process may use now: those it may run on, less the other work the load average shows
    (this process's own run counted as one), at least 1."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    try:
        others = max(0.0, os.getloadavg()[0] - 1.0)
    except OSError:
        others = 0.0
    return max(1, min(cores, int(cores - others + 0.5)))


class ProcessExecutor(_Pooled):
    """A pool of ``jobs`` local worker processes, started at the first task (``fn`` and the items are
    pickled: module-level functions and plain data)."""

    def __init__(self, jobs: int | None = None) -> None:
        workers = max(1, int(jobs or os.cpu_count() or 1))
        super().__init__(workers, f"{workers} local processes",
                         lambda: ProcessPoolExecutor(max_workers=workers, mp_context=pool_context()))

    def submit(self, fn: Callable, *args) -> Future:
        return super().submit(_one_blas_thread, fn, *args)


_WORKER_READY = False


def _one_blas_thread(fn: Callable, *args):
    """A task in a worker: ``fn(*args)`` on one BLAS thread (:func:`pgdcli.blas.one_blas_thread`): the
    workers are the parallelism, and a task computes the same floats wherever it runs
    (:func:`pgdcli.solve` runs on one BLAS thread too). The worker's allocator reuses freed memory as
    this process's does (:func:`pgdcli.pages.reuse_freed_memory`: Dask's workers turn that off)."""
    global _WORKER_READY
    if not _WORKER_READY:
        from .pages import reuse_freed_memory  # numpy: not loaded by a command that runs no task

        reuse_freed_memory()
        _WORKER_READY = True
    with one_blas_thread():
        return fn(*args)


class DaskExecutor(Executor):
    """Tasks on the workers of ``client`` (a ``distributed.Client``).

    Parameters
    ----------
    client : distributed.Client
    cluster : distributed.LocalCluster, optional
        A cluster started for this executor: closed with it, as is the client.
    owns_client : bool
        Close the client with the executor.
    """

    def __init__(self, client, cluster=None, owns_client: bool = False) -> None:
        super().__init__()
        self.client, self.cluster = client, cluster
        self._owns_client = owns_client or cluster is not None
        self._shared: OrderedDict = OrderedDict()  # id(fn) -> (fn, future of it on the workers)
        self.address = str(getattr(client.scheduler, "address", "") or "")
        self.refresh()

    def refresh(self) -> None:
        """Count the workers' threads again (workers come and go)."""
        try:
            self.workers = max(1, sum(self.client.nthreads().values()))
        except Exception:  # noqa: BLE001 - a count for sizing work; the tasks report real failures
            self.workers = max(1, self.workers)
        kind = "local Dask cluster" if self.cluster is not None else "Dask cluster"
        self.description = f"{kind} at {self.address}, {self.workers} worker thread(s)"

    @property
    def dashboard(self) -> str | None:
        """The link of the scheduler's dashboard, or None when it serves none (bokeh not installed)."""
        try:
            info = self.client.scheduler_info()
            if "dashboard" not in info.get("services", {}):
                return None
            return self.client.dashboard_link
        except Exception:  # noqa: BLE001 - a courtesy line, never a failure
            return None

    # ------------------------------------------------------------------ tasks
    def _handle(self, fn: Callable):
        """The future of ``fn`` on the workers, scattered once (again after a restart lost it)."""
        entry = self._shared.get(id(fn))
        if entry is not None and entry[0] is fn and entry[1].status == "finished":
            self._shared.move_to_end(id(fn))
            return entry[1]
        [future] = self._retried(lambda: self.client.scatter([fn], broadcast=True, hash=False), "send a function")
        self._shared[id(fn)] = (fn, future)
        while len(self._shared) > SHARED:
            self._shared.popitem(last=False)
        return future

    def submit(self, fn: Callable, *args):
        return self.client.submit(_one_blas_thread, self._handle(fn), *args, pure=False)

    def _result(self, fn: Callable, item, future):
        """The value of ``fn(item)`` whose task is ``future``; a cancelled task is submitted again."""
        for attempt in range(RESUBMITS + 1):
            try:
                return future.result()
            except CancelledError:
                if attempt == RESUBMITS:
                    raise ClusterError(f"a task was cancelled {RESUBMITS + 1} times on the {self.description} "
                                       f"(the cluster restarted or lost its workers)") from None
            except Exception as exc:  # noqa: BLE001 - the cluster's own failures, named; the task's re-raised
                raise _cluster_failure(exc, self.description) or exc
            future = self._resubmitted(fn, item)
        raise AssertionError("unreachable")

    def _resubmitted(self, fn: Callable, item):
        """``fn(item)`` submitted again once the cluster has a worker (a restart may still be under way)."""
        self._retried(lambda: self.client.wait_for_workers(1, timeout=RESTART_TIMEOUT), "wait for a worker")
        return self.submit(fn, item)

    def _retried(self, action: Callable, what: str):
        """``action()``, tried again while the cluster restarts (its connections closed meanwhile)."""
        for attempt in range(RESUBMITS + 1):
            try:
                return action()
            except Exception as exc:  # noqa: BLE001 - a cluster in flux fails in many classes; the last is named
                if attempt == RESUBMITS:
                    raise ClusterError(f"cannot {what} on the {self.description} "
                                       f"({' '.join(str(exc).split()) or type(exc).__name__})") from None
                time.sleep(0.5 * (attempt + 1))
        raise AssertionError("unreachable")

    def map(self, fn: Callable, items: Iterable) -> Iterator:
        self.refresh()
        return super().map(fn, items)

    def as_completed(self, fn: Callable, items: Iterable) -> Iterator[tuple[int, object]]:
        from distributed import as_completed

        items = list(items)
        index = {}
        for i, item in enumerate(items):
            index[self.submit(fn, item)] = i
        tries = dict.fromkeys(range(len(items)), 0)
        finished = as_completed(list(index))
        try:
            for future in finished:
                i = index.pop(future)
                if future.status == "cancelled" and tries[i] < RESUBMITS:
                    tries[i] += 1
                    again = self._resubmitted(fn, items[i])
                    index[again] = i
                    finished.add(again)
                    continue
                self._count()
                yield i, _Outcome(self, future)
        finally:
            for future in index:
                future.release()

    def close(self, wait: bool = True) -> None:
        self._shared.clear()
        if self._owns_client:
            try:
                self.client.close()
            finally:
                if self.cluster is not None:
                    self.cluster.close()


class _Outcome:
    """A finished task of :meth:`DaskExecutor.as_completed`: ``result()`` its value, or raises what it
    raised (the cluster's own failures as a ClusterError)."""

    def __init__(self, executor: DaskExecutor, future):
        self.executor, self.future = executor, future

    def result(self):
        try:
            return self.future.result()
        except CancelledError:
            raise ClusterError(f"a task was cancelled {RESUBMITS + 1} times on the {self.executor.description} "
                               f"(the cluster restarted or lost its workers)") from None
        except Exception as exc:  # noqa: BLE001
            raise _cluster_failure(exc, self.executor.description) or exc


def _cluster_failure(exc: Exception, description: str) -> ClusterError | None:
    """A ClusterError for a failure of the cluster itself (not of the task's own code), else None."""
    from distributed import KilledWorker

    if isinstance(exc, KilledWorker):
        return ClusterError(f"a task ended {ALLOWED_FAILURES} workers of the {description} (they died while "
                            f"running it: out of memory?)")
    if isinstance(exc, (OSError, TimeoutError)) and type(exc).__module__.startswith(("distributed", "tornado")):
        return ClusterError(f"lost the {description}: {' '.join(str(exc).split()) or type(exc).__name__}")
    return None


SERIAL = SerialExecutor()
_CURRENT: contextvars.ContextVar[Executor | None] = contextvars.ContextVar("pgdcli_executor", default=None)


def current() -> Executor:
    """The executor in effect (:func:`using`), else :data:`SERIAL`."""
    return _CURRENT.get() or SERIAL


@contextlib.contextmanager
def using(executor):
    """Make ``executor`` (anything :func:`as_executor` takes; None: leave the one in effect) the
    executor in effect for the block."""
    if executor is None:
        yield current()
        return
    executor = as_executor(executor)
    token = _CURRENT.set(executor)
    try:
        yield executor
    finally:
        _CURRENT.reset(token)


def as_executor(executor) -> Executor:
    """An :class:`Executor` of ``executor``: an Executor itself, None (:data:`SERIAL`), a number of
    local processes (int), or a ``distributed.Client``.

    Raises
    ------
    TypeError
        Anything else.
    """
    if executor is None:
        return SERIAL
    if isinstance(executor, Executor):
        return executor
    if isinstance(executor, int) and not isinstance(executor, bool) and executor >= 1:
        return SERIAL if executor == 1 else ProcessExecutor(executor)
    if all(hasattr(executor, name) for name in ("scatter", "submit", "gather", "scheduler_info")):
        return DaskExecutor(executor)
    raise TypeError(f"executor: expected a pgdcli Executor, a number of processes or a distributed.Client, "
                    f"got {type(executor).__name__}")
