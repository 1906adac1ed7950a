"""The executor interface, and its runner of a task in a worker process.

:class:`Executor` is the interface of :mod:`pgdcli.executors` (see there), :class:`SerialExecutor` the
executor of this process; :func:`run_in_worker` runs a task in a pool's or a cluster's worker.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, as_completed
from typing import Callable, Iterable, Iterator

from .blas import one_blas_thread

__all__ = ["Executor", "SerialExecutor", "run_in_worker"]


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
        self._count(self._tasks_in(fn, item))
        return value

    def _tasks_in(self, fn: Callable, item) -> int:
        """How many of the caller's tasks the task of ``fn(item)`` holds (their count in :attr:`finished`)."""
        return 1

    def _result(self, fn: Callable, item, future):
        return future.result()

    def _count(self, tasks: int = 1) -> None:
        self.finished += tasks
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



_WORKER_READY = False


def run_in_worker(fn: Callable, *args):
    """A task in a worker process: ``fn(*args)`` on one BLAS thread (:func:`pgdcli.blas.one_blas_thread`): the
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

