"""Where independent tasks run: in this process, in local worker processes, or on a Dask cluster.

The numerical code hands independent pieces of work (the cross march's batches of trajectories, the
reference's chunks of samples, the specs of a family, the partitions of a large query) to an
*executor*, a small :mod:`concurrent.futures`-style interface:

- ``map(fn, items)``: ``fn(item)`` for every item, yielded in order as they are needed, with at most
  :attr:`Executor.window` tasks in flight (the memory of the results waiting is bounded); ``fn`` is
  sent to the workers once, not with every item; an iterator's items are taken as they are needed
  (a large file read as it goes), a sequence's may be sent several to a task;
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

On a cluster (:mod:`pgdcli.dask_executor`), a task's function is sent to every worker once
(``Client.scatter``, broadcast) and each task carries only its items: ``map`` sends a call's items as
runs of consecutive items, a few tasks a worker (the scheduler's cost is per task), under keys named
after the function. Faults: the scheduler runs again elsewhere a task whose worker died, and
recomputes results lost with it (the tasks are pure functions of their inputs); a task cancelled
under us (``Client.restart``) is submitted again, its function scattered again, a few times. Either
way the results are the ones an undisturbed run gives. A task that killed several workers, or a
scheduler gone away, is a :class:`~pgdcli.errors.ClusterError`.

The executor in effect, :func:`current`, is set for a block by :func:`using`; :func:`pgdcli.solve`
sets it from its ``executor`` argument, so the layers below reach it without every signature
between them carrying it. Imports nothing of the package but its executor modules, errors and BLAS limiter (a leaf
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
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from typing import Callable

from .dask_executor import DaskExecutor
from .executor_base import Executor, SerialExecutor, run_in_worker

__all__ = ["Executor", "SerialExecutor", "ThreadExecutor", "ProcessExecutor", "DaskExecutor", "current", "using",
           "as_executor", "free_cores", "pool_context"]


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
        return super().submit(run_in_worker, fn, *args)



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
