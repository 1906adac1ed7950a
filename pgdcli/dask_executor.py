"""Tasks on a Dask cluster: :class:`DaskExecutor`, the executor of a ``distributed.Client``.

Dask is imported only inside its methods (the client passed in has loaded it already).
"""

from __future__ import annotations

import time
import uuid
from collections import OrderedDict
from concurrent.futures import CancelledError
from typing import Callable, Iterable, Iterator, Sequence

from .errors import ClusterError
from .executor_base import Executor, run_in_worker

__all__ = ["DaskExecutor", "RESUBMITS", "ALLOWED_FAILURES", "SHARED", "RESTART_TIMEOUT", "TASKS_PER_WORKER"]


#: Times a cancelled task is submitted again.
RESUBMITS = 3
#: Workers a task may kill before the scheduler gives it up (distributed's ``allowed-failures``).
ALLOWED_FAILURES = 3
#: Functions kept scattered on the workers (the most recent ones).
SHARED = 4
#: Seconds to wait for a worker before a cancelled task is submitted again.
RESTART_TIMEOUT = 60.0
#: Tasks per worker that one :meth:`DaskExecutor.map` call's items are cut into (consecutive items in a
#: task): the scheduler's cost is per task, and a few tasks a worker still even out unequal items.
TASKS_PER_WORKER = 2


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
        self._runs: OrderedDict = OrderedDict()  # id(fn) -> _Each(fn)
        self._slots: list[str] = []  # a worker's address once per thread
        self.address = str(getattr(client.scheduler, "address", "") or "")
        self.refresh()

    def refresh(self) -> None:
        """Count the workers' threads again (workers come and go)."""
        try:
            threads = self.client.nthreads()
            self.workers = max(1, sum(threads.values()))
            self._slots = [worker for worker in sorted(threads) for _ in range(threads[worker])]
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

    def submit(self, fn: Callable, *args, worker: str | None = None):
        """The future of ``fn(*args)``, on ``worker`` if it is still there (else where the scheduler puts it)."""
        # a key named after the work: the scheduler estimates a task's duration from the others of its
        # name, and the dashboard shows it
        placed = {} if worker is None else {"workers": [worker], "allow_other_workers": True}
        return self.client.submit(run_in_worker, self._handle(fn), *args, key=f"{_task_name(fn)}-{uuid.uuid4().hex}",
                                  **placed)

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
        """``fn(item)`` for every item, in order. The items of a sequence (a list, a tuple) go out in
        :data:`TASKS_PER_WORKER` tasks a worker, runs of consecutive items of sizes that differ by one at
        most; an iterator's one a task, taken as the window allows (a large file read as it goes)."""
        self.refresh()
        if not isinstance(items, Sequence):
            yield from super().map(fn, items)
            return
        count = min(len(items), TASKS_PER_WORKER * self.workers)
        bounds = [len(items) * i // count for i in range(count + 1)] if count else [0]
        runs = [items[a:b] for a, b in zip(bounds, bounds[1:])]
        each = self._each(fn)
        # the runs dealt to the workers' threads in turn: the scheduler, left to itself, gave one worker
        # more of them (365 tasks against 204 in one build of two workers), and a call waited for that one
        slots = self._slots or [None]
        futures = [self.submit(each, run, worker=slots[i % len(slots)]) for i, run in enumerate(runs)]
        try:
            for run, future in zip(runs, futures):
                yield from self._taken(each, run, future)
        finally:
            for future in futures:
                future.cancel()

    def _tasks_in(self, fn: Callable, item) -> int:
        return len(item) if isinstance(fn, _Each) else 1

    def _each(self, fn: Callable) -> "_Each":
        """The task of a run of items of ``fn``: one object per function, so that it is scattered once."""
        entry = self._runs.get(id(fn))
        if entry is None or entry.fn is not fn:
            entry = self._runs[id(fn)] = _Each(fn)
            while len(self._runs) > SHARED:
                self._runs.popitem(last=False)
        return entry

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
        self._runs.clear()
        if self._owns_client:
            try:
                self.client.close()
            finally:
                if self.cluster is not None:
                    self.cluster.close()


def _task_name(fn: Callable) -> str:
    """``pgdcli-`` and the name of ``fn`` (of the function of an :class:`_Each` run), for Dask's keys."""
    fn = fn.fn if isinstance(fn, _Each) else fn
    name = getattr(fn, "__name__", type(fn).__name__)
    return "pgdcli-" + (name.strip("_").replace("_", "-").lower() or "task")


class _Each:
    """A task of consecutive items: ``[fn(item) for item in items]``."""

    def __init__(self, fn: Callable):
        self.fn = fn

    def __call__(self, items: list) -> list:
        return [self.fn(item) for item in items]


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


