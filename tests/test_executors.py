"""The executors (pgdcli.executors): order, laziness, the window of tasks in flight, failures, the
executor in effect. The Dask executor is tested on a real LocalCluster in test_cluster.py.
"""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from pgdcli import executors
from pgdcli.tensors import fiber_cross
from pgdcli.tensors.fiber_cross import vector_cross


def square(x):
    return x * x


def pid_of(_):
    return os.getpid()


def fails_on_three(x):
    if x == 3:
        raise ValueError("three")
    return x


class Recording(executors.SerialExecutor):
    """A serial executor that records how many tasks were submitted ahead of the results taken."""

    def __init__(self, workers: int):
        super().__init__()
        self.workers, self.submitted, self.ahead = workers, 0, 0

    def submit(self, fn, *args):
        self.submitted += 1
        self.ahead = max(self.ahead, self.submitted - self.finished)
        return super().submit(fn, *args)

    map = executors.Executor.map  # the windowed map of the interface, over submit


def test_serial_map_is_lazy_and_in_order():
    seen = []

    def record(x):
        seen.append(x)
        return -x

    results = executors.SERIAL.map(record, range(5))
    assert seen == []
    assert next(results) == 0 and seen == [0]
    assert list(results) == [-1, -2, -3, -4]


def test_map_keeps_at_most_a_window_of_tasks_in_flight():
    executor = Recording(workers=3)
    assert list(executor.map(square, range(40))) == [x * x for x in range(40)]
    assert executor.ahead == executor.window == 7
    assert executor.finished == 40


def test_process_pool_map_and_as_completed():
    with executors.ProcessExecutor(2) as pool:
        assert list(pool.map(square, range(20))) == [x * x for x in range(20)]
        done = dict(pool.as_completed(square, range(6)))
        assert sorted(done) == list(range(6)) and all(done[i].result() == i * i for i in done)
        assert set(pool.map(pid_of, range(8))) != {os.getpid()}  # in other processes
        with pytest.raises(ValueError, match="three"):
            list(pool.map(fails_on_three, range(6)))


def test_as_completed_hands_a_task_failure_to_its_future_only():
    outcomes = dict(executors.SERIAL.as_completed(fails_on_three, range(5)))
    assert [outcomes[i].result() for i in (0, 1, 2, 4)] == [0, 1, 2, 4]
    with pytest.raises(ValueError, match="three"):
        outcomes[3].result()


def test_the_executor_in_effect_is_set_for_a_block_and_in_this_thread_only():
    assert executors.current() is executors.SERIAL
    pool = executors.ProcessExecutor(2)
    seen = []
    with executors.using(pool) as given:
        assert given is pool and executors.current() is pool
        thread = threading.Thread(target=lambda: seen.append(executors.current()))
        thread.start()
        thread.join()
        with executors.using(None):
            assert executors.current() is pool
        with executors.using(executors.SERIAL):
            assert executors.current() is executors.SERIAL
        assert executors.current() is pool
    assert executors.current() is executors.SERIAL
    assert seen == [executors.SERIAL]


def test_as_executor_takes_executors_process_counts_and_refuses_the_rest():
    assert executors.as_executor(None) is executors.SERIAL
    assert executors.as_executor(1) is executors.SERIAL
    pool = executors.as_executor(3)
    assert isinstance(pool, executors.ProcessExecutor) and pool.workers == 3
    for wrong in ("tcp://x:8786", 0, True, 2.5):
        with pytest.raises(TypeError, match="executor"):
            executors.as_executor(wrong)


def test_vector_cross_through_an_executor_is_the_same_train_bit_for_bit(monkeypatch):
    # the cross asks for batches (64 points each here); an executor's map (the windowed one) must not
    # change a float
    monkeypatch.setattr(fiber_cross, "BATCH_FLOATS", 5 * 64)
    grid = np.linspace(0.0, 1.0, 9)

    def function(indices):  # a smooth vector-valued function of four indices: (5, P)
        x = grid[indices]
        base = np.exp(-x[:, 0] * x[:, 1]) + np.sin(x[:, 2] + 2.0 * x[:, 3])
        return np.stack([base * (k + 1) + x[:, k % 4] ** 2 for k in range(5)])

    def cross(**extra):
        return vector_cross(function, 5, (9, 9, 9, 9), 1e-8, rng=np.random.default_rng(3), **extra)

    executor = Recording(workers=2)
    plain, mapped = cross(), cross(map=executor.map)
    assert executor.finished > 3 * plain.sweeps  # several batches a half sweep
    assert plain.converged and mapped.converged
    assert all(np.array_equal(a, b) for a, b in zip(plain.train.cores, mapped.train.cores))


def test_thread_executor_runs_every_task_and_hands_out_its_failure():
    def task(item):
        if item == 3:
            raise ValueError("three")
        return item * item

    running = threading.active_count()
    with executors.ThreadExecutor(2) as threads:
        assert list(threads.map(task, [0, 1, 2])) == [0, 1, 4]
        outcomes = dict(threads.as_completed(task, range(5)))
        assert sorted(outcomes) == list(range(5))
        assert [outcomes[i].result() for i in (0, 1, 2, 4)] == [0, 1, 4, 16]
        with pytest.raises(ValueError, match="three"):
            outcomes[3].result()
    assert threading.active_count() == running  # its threads ended with the block


def test_free_cores_leaves_out_the_other_work_the_load_shows(monkeypatch):
    monkeypatch.setattr(executors.os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    for load, free in ((0.2, 4), (1.0, 4), (2.0, 3), (3.6, 1), (9.0, 1)):
        monkeypatch.setattr(executors.os, "getloadavg", lambda load=load: (load, load, load))
        assert executors.free_cores() == free
