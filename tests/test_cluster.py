"""Builds, checks and queries on a real Dask LocalCluster (worker processes): the same results as
without the cluster, bit for bit, and the same after a worker is killed mid-build
(pgdcli.cluster, pgdcli.executors.DaskExecutor, and the commands' --scheduler / --workers).

One cluster of two single-threaded worker processes serves the module.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import PROBLEMS

import pgdcli
import pgdcli.pages
from pgdcli import Codebook, executors, parse_spec
from pgdcli.checks.verify import verify
from pgdcli.cli.main import cli
from pgdcli.cluster import connect, local_cluster
from pgdcli.errors import ClusterError
from pgdcli.family import FamilyFailure, solve_many
from pgdcli.tensors import fiber_cross

distributed = pytest.importorskip("distributed")

# predator and prey through the cross march: 10^4 grid nodes, the nodes of a, b and both initial values
CROSS = """
name: predator_prey4
coordinates:
  t: {domain: [0, 2]}
  a: {domain: [0.9, 1.1], nodes: 10}
  b: {domain: [0.3, 0.5], nodes: 10}
  x0: {domain: [0.8, 1.2], nodes: 10}
  y0: {domain: [0.4, 0.6], nodes: 10}
unknowns:
  x: {initial: x0}
  y: {initial: y0}
equations:
  - "der(x) = a*x - b*x*y"
  - "der(y) = 0.5*x*y - 0.7*y"
solver:
  tolerance: 1e-5
  march: cross
"""


@pytest.fixture(scope="module")
def cluster():
    """A LocalCluster of two worker processes (one thread each) and a client of it."""
    local = local_cluster(2)
    client = distributed.Client(local)
    yield client
    client.close()
    local.close()


@pytest.fixture
def small_batches(monkeypatch):
    """The cross's batches of 256 trajectories (many tasks: a fault lands mid-build)."""
    monkeypatch.setattr(fiber_cross, "BATCH_FLOATS", 256 * 82)  # 2 unknowns x 41 stored times


def same_codebook(a: Codebook, b: Codebook) -> bool:
    """Every array of every unknown (CP factors, TT cores) equal bit for bit, and the same report (the wall
    times aside)."""
    for u in a.fields:
        fa, fb = a.fields[u], b.fields[u]
        if type(fa) is not type(fb) or not _same_arrays(vars(fa), vars(fb)):
            return False
    skip = {"wall_time", "gate_time"}
    ra, rb = ({k: v for k, v in r.items() if k not in skip} for r in (a.report, b.report))
    return ra.keys() == rb.keys() and all(_equal(ra[k], rb[k]) for k in ra)


def _same_arrays(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same_arrays(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same_arrays(x, y) for x, y in zip(a, b))
    return _equal(a, b)


def _equal(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return np.array_equal(a, b, equal_nan=a.dtype.kind == "f" and b.dtype.kind == "f")


@pytest.fixture(scope="module")
def cross_here():
    """The predator-prey codebook built in this process (the reference of the cluster's builds)."""
    result = pgdcli.solve(parse_spec(CROSS, source="predator_prey4.yaml"))
    assert result.converged, result.message
    return result


def test_a_cross_march_build_on_the_cluster_is_the_local_codebook_bit_for_bit(cluster, cross_here, monkeypatch):
    executor = executors.as_executor(cluster)
    sent, scatter = [], cluster.scatter

    def counted(data, **kw):
        sent.append(type(data[0].fn).__name__)  # a run of items of the function
        return scatter(data, **kw)

    monkeypatch.setattr(cluster, "scatter", counted)
    result = pgdcli.solve(parse_spec(CROSS, source="predator_prey4.yaml"), executor=executor)
    assert result.converged, result.message
    assert executor.finished >= 10  # the batches ran as tasks
    assert "2 marches" in result.message and sent == ["_Picked"] * 2  # each march's steps sent once
    assert result.codebook.report["march"] == "cross"
    assert same_codebook(result.codebook, cross_here.codebook)


def _page_faults_of_freed_arrays(_) -> int:
    """Pages faulted in while a 1 MiB array is allocated, written and freed 100 times."""
    import resource

    np.ones(1 << 17)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(100):
        np.ones(1 << 17).sum()
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


@pytest.mark.skipif(not pgdcli.pages.reuse_freed_memory(), reason="not glibc's allocator")
def test_a_map_on_the_cluster_sends_runs_of_items_in_order(cluster, monkeypatch):
    executor = executors.as_executor(cluster)
    submitted, submit = [], cluster.submit
    monkeypatch.setattr(cluster, "submit", lambda fn, *a, **kw: submitted.append((a[-1], kw)) or submit(fn, *a, **kw))
    assert list(executor.map(np.square, range(11))) == [i * i for i in range(11)]
    assert executor.finished == 11  # counted as items
    # two tasks a worker, of consecutive items: the scheduler pays per task
    assert [list(run) for run, _ in submitted] == [[0, 1], [2, 3, 4], [5, 6, 7], [8, 9, 10]]
    # named after the work, distinct: the scheduler's duration estimates and the dashboard go by name
    keys = [kw["key"] for _, kw in submitted]
    assert all(key.startswith("pgdcli-square-") for key in keys) and len(set(keys)) == 4
    # dealt to the workers in turn (each may still go elsewhere: a worker may have left)
    first, second = sorted(cluster.nthreads())
    assert [kw["workers"] for _, kw in submitted] == [[first], [second]] * 2
    assert all(kw["allow_other_workers"] for _, kw in submitted)
    submitted.clear()  # an iterator's items one a task, taken as they are needed (a file read as it goes)
    assert list(executor.map(np.square, iter(range(5)))) == [i * i for i in range(5)]
    assert [run for run, _ in submitted] == list(range(5))
    assert list(executor.map(np.square, [])) == [] and list(executor.map(np.negative, [3])) == [-3]


def test_a_task_on_a_worker_reuses_freed_memory(cluster):
    # Dask starts its workers with MALLOC_TRIM_THRESHOLD_ set: without pgdcli's setting every array
    # above 128 KiB would be a fresh mapping, its 256 pages faulted in again at each of the 100 rounds
    [faults] = executors.as_executor(cluster).map(_page_faults_of_freed_arrays, [None])
    assert faults < 100 * 256 // 10


def _worker_pids(client) -> list[int]:
    return list(client.run(os.getpid).values())


class KillAfter(distributed.SchedulerPlugin):
    """A scheduler plugin that kills (SIGKILL) the process of a worker with work in flight once the
    scheduler has recorded ``count`` tasks finished, and before it records another: the kill lands after
    exactly that many tasks, with tasks lost on the worker killed, however fast or slow the tasks and the
    machine run. The nanny starts another worker.

    At the ``count``-th finished task the worker with the most other tasks in flight is killed; when no
    worker has any (a slow client had not sent the next ones yet), the one that is sent the next task
    is, at that moment: no task can finish in between, none being in flight."""

    name = "kill-after"

    def __init__(self, scheduler, count: int):
        self.scheduler, self.count, self.finished = scheduler, count, 0
        self.killed: tuple | None = None  # (pid, tasks finished then, tasks lost in flight)

    def transition(self, key, start, finish, *args, **kwargs):
        if self.killed is not None:
            return
        if (start, finish) == ("processing", "memory"):
            self.finished += 1
            if self.finished == self.count:
                running = {ws: [ts for ts in ws.processing if ts.key != key]
                           for ws in self.scheduler.workers.values()}
                victim = max(running, key=lambda ws: len(running[ws]), default=None)
                if victim is not None and running[victim]:
                    self._kill(victim, len(running[victim]))
        elif finish == "processing" and self.finished == self.count:
            victim = self.scheduler.tasks[key].processing_on
            if victim is not None:
                self._kill(victim, len(victim.processing))

    def _kill(self, victim, lost: int) -> None:
        os.kill(victim.pid, signal.SIGKILL)
        self.killed = (victim.pid, self.finished, lost)


class Killed(SimpleNamespace):
    """What :class:`KillAfter` did: ``pid``, ``finished`` (tasks finished then), ``lost`` (tasks in flight)."""


@contextlib.contextmanager
def killing_a_worker_after(client, count: int):
    """A worker process killed once ``count`` tasks have finished, while the block runs (the scheduler of a
    LocalCluster runs on this machine: it can kill its workers' processes)."""
    found = Killed()
    client.run_on_scheduler(_install_kill_after, count=count)
    try:
        yield found
    finally:
        killed = client.run_on_scheduler(_remove_kill_after)
        if killed is not None:
            found.pid, found.finished, found.lost = killed
        client.wait_for_workers(2, timeout=300)  # the nanny starts a worker again, on a loaded machine too


def _install_kill_after(dask_scheduler, count):  # runs on the scheduler's event loop
    dask_scheduler.add_plugin(KillAfter(dask_scheduler, count))


def _remove_kill_after(dask_scheduler):
    killed = dask_scheduler.plugins[KillAfter.name].killed
    dask_scheduler.remove_plugin(name=KillAfter.name)
    return killed


@pytest.mark.slow
def test_a_worker_killed_mid_build_gives_the_same_codebook(cluster, small_batches):
    here = pgdcli.solve(parse_spec(CROSS, source="predator_prey4.yaml"))
    executor = executors.as_executor(cluster)
    with killing_a_worker_after(cluster, 10) as plugin:
        result = pgdcli.solve(parse_spec(CROSS, source="predator_prey4.yaml"), executor=executor)
    assert plugin.finished == 10 and plugin.lost >= 1  # killed mid-build, work lost
    assert executor.finished > 10 + 10
    assert result.converged, result.message
    assert same_codebook(result.codebook, here.codebook)
    assert plugin.pid not in _worker_pids(cluster)


@pytest.mark.slow
def test_a_cluster_restarted_mid_build_gives_the_same_codebook(cluster, small_batches, monkeypatch):
    here = pgdcli.solve(parse_spec(CROSS, source="predator_prey4.yaml"))
    executor = executors.as_executor(cluster)
    resubmitted, resubmit = [], executor._resubmitted
    monkeypatch.setattr(executor, "_resubmitted", lambda *a: resubmitted.append(a) or resubmit(*a))

    taken, take = [], executor._result

    def restart_at_the_10th(fn, item, future):  # the 10th task's result about to be taken: it is in flight
        taken.append(item)
        if len(taken) == 10:
            cluster.restart(timeout=300)  # every task in flight cancelled, the scattered schedule lost
        return take(fn, item, future)

    monkeypatch.setattr(executor, "_result", restart_at_the_10th)
    result = pgdcli.solve(parse_spec(CROSS, source="predator_prey4.yaml"), executor=executor)
    assert resubmitted and executor.finished > 10 + 10  # restarted mid-build: tasks cancelled and sent again
    assert result.converged, result.message
    assert same_codebook(result.codebook, here.codebook)


def test_verify_on_the_cluster_is_verify_here_bit_for_bit(cluster, cross_here):
    here = verify(cross_here.codebook, samples=100, times=4, jobs=1)
    there = verify(cross_here.codebook, samples=100, times=4, executor=cluster)
    assert here.settings["parameter_points"] == there.settings["parameter_points"] == 100 + 16
    assert there.settings["cluster"] == cluster.scheduler.address
    for u in here.reference:
        assert np.array_equal(here.reference[u], there.reference[u])
        assert here.unknowns[u].max_abs_error == there.unknowns[u].max_abs_error
    assert here.passed() and there.passed()


@pytest.mark.slow
def test_a_worker_killed_mid_verify_gives_the_same_report(cluster, cross_here):
    here = verify(cross_here.codebook, samples=2000, max_corners=0, times=2, jobs=1)
    executor = executors.as_executor(cluster)
    with killing_a_worker_after(cluster, 3) as plugin:
        there = verify(cross_here.codebook, samples=2000, max_corners=0, times=2, executor=executor)
    assert plugin.finished == 3 and plugin.lost >= 1 and executor.finished == 16  # 16 chunks of 125 points
    for u in here.reference:
        assert np.array_equal(here.reference[u], there.reference[u])
    assert plugin.pid not in _worker_pids(cluster)


def test_verify_on_the_cluster_stops_at_its_time_budget(cluster, cross_here, tmp_path):
    import json

    from pgdcli.codebook import io as codebook_io

    cb = cross_here.codebook
    stiff = cb.spec_text.replace('"der(y) = 0.5*x*y - 0.7*y"', '"der(y) = 0.5*x*y - 1e8*y"')  # hours of DOP853
    assert stiff != cb.spec_text
    path = tmp_path / "stiff.h5"
    path.write_bytes(codebook_io.to_bytes(Codebook(cb.coordinates, cb.fields, name=cb.name, spec_text=stiff,
                                                   report=cb.report)))
    started = time.monotonic()
    result = CliRunner().invoke(cli, ["verify", str(path), "--samples", "500", "--max-seconds", "3", "--scheduler",
                                      cluster.scheduler.address, "--format", "json", "-q"])
    assert result.exit_code == 1, result.output
    report = json.loads(result.stdout)
    assert report["complete"] is False and report["settings"]["not_checked"] > 0
    assert time.monotonic() - started < 120  # the workers stopped too


def test_a_family_on_the_cluster_is_the_family_here(cluster):
    texts = {"spring": (PROBLEMS / "spring.yaml").read_text(), "relaxation": (PROBLEMS / "relaxation.yaml").read_text(),
             "parametric": (PROBLEMS / "parametric.yaml").read_text()}
    problems = [parse_spec(text, source=f"{name}.yaml") for name, text in texts.items()]
    here = dict(solve_many(problems))
    there = dict(solve_many(problems, executor=cluster))
    assert sorted(here) == sorted(there) == [0, 1, 2]
    for i in here:
        assert here[i].converged and there[i].converged
        assert same_codebook(here[i].codebook, there[i].codebook)


def test_a_failing_member_of_a_family_does_not_stop_the_others(cluster):
    good = parse_spec((PROBLEMS / "parametric.yaml").read_text(), source="parametric.yaml")
    bad = SimpleNamespace(source_text="name: [unclosed", source="bad.yaml", name="bad")  # fails in its task
    outcomes = dict(solve_many([bad, good], executor=cluster))
    assert isinstance(outcomes[0], FamilyFailure) and "bad.yaml" in outcomes[0].message
    assert outcomes[1].converged


def test_codebook_evaluate_on_dask_arrays_on_the_cluster(cluster, cross_here):
    import dask.array as da

    cb = cross_here.codebook
    rng = np.random.default_rng(4)
    points = {c.name: rng.uniform(*c.domain, size=5000) for c in cb.coordinates}
    lazy = cb.evaluate({n: da.from_array(v, chunks=1200) for n, v in points.items()})
    assert lazy["x"].chunks == ((1200, 1200, 1200, 1200, 200),)
    values = cluster.compute(lazy, sync=True)
    # block by block, the values of evaluate on the block's arrays (a batch's rounding depends on its size)
    blocks = [cb.evaluate({n: v[s:s + 1200] for n, v in points.items()}) for s in range(0, 5000, 1200)]
    whole = cb.evaluate(points)
    for u in cb.unknown_names:
        assert np.array_equal(values[u], np.concatenate([b[u] for b in blocks]))
        np.testing.assert_allclose(values[u], whole[u], rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------------------------
# the 15-coordinate chain of problems/chain15.yaml
# ----------------------------------------------------------------------------------------------
def chain_rhs(k, m2, c, beta, amplitude):
    """Three bodies between two walls on four springs (force k e + beta e^3 at extension e), damped, the
    first driven by amplitude * cos(2 t); masses 1, m2, 1. Written from the physics, not the spec."""
    masses = np.array([1.0, m2, 1.0])

    def rhs(t, y):
        x, v = y[:3], y[3:]
        extension = np.array([x[0], x[1] - x[0], x[2] - x[1], -x[2]])
        force = k * extension + beta * extension ** 3
        drive = np.array([amplitude * np.cos(2.0 * t), 0.0, 0.0])
        return np.concatenate([v, (force[1:] - force[:-1] - c * v + drive) / masses])

    return rhs


def cheap_chain() -> str:
    """The shipped chain at 5 nodes a parameter, tolerance 1e-5 and a smaller box of initial states (its
    full build: benchmarks/cluster_scaling.py --chain). The time slabs keep their 6 nodes: at 5 the
    interpolation between time nodes alone is about the tolerance, and the build marches three times over
    to meet it instead of once."""
    text = (PROBLEMS / "chain15.yaml").read_text()
    for full, cheap in (("nodes: 6}", "nodes: 5}"), ("tolerance: 1e-6", "tolerance: 1e-5"),
                        ("[-0.15, 0.15]", "[-0.1, 0.1]"), ("[-0.3, 0.3]", "[-0.2, 0.2]"),
                        ("t:    {domain: [0, 1], nodes: 5}", "t:    {domain: [0, 1], nodes: 6}")):
        assert full in text
        text = text.replace(full, cheap)
    return text


@pytest.mark.slow
def test_the_15_coordinate_chain_on_the_cluster_against_solve_ivp(cluster):
    from scipy.integrate import solve_ivp

    problem = parse_spec(cheap_chain(), source="chain15.yaml")
    assert len(problem.coordinates) == 15
    result = pgdcli.solve(problem, executor=cluster)
    assert result.converged, result.message
    assert result.codebook.report["march"] == "cross"
    cb, rng = result.codebook, np.random.default_rng(15)
    times = np.linspace(0.0, 1.0, 11)
    names = ["k1", "k2", "k3", "k4", "m2", "c", "beta", "A", "x10", "x20", "x30", "v10", "v20", "v30"]
    worst = 0.0
    for _ in range(30):  # random points of the box, off the nodes
        p = {n: rng.uniform(*cb.coordinate(n).domain) for n in names}
        k = np.array([p["k1"], p["k2"], p["k3"], p["k4"]])
        y0 = [p[n] for n in ("x10", "x20", "x30", "v10", "v20", "v30")]
        ref = solve_ivp(chain_rhs(k, p["m2"], p["c"], p["beta"], p["A"]), (0.0, 1.0), y0, method="DOP853",
                        rtol=1e-12, atol=1e-12, t_eval=times)
        got = cb.evaluate({"t": times, **p})
        for i, u in enumerate(("x1", "x2", "x3", "v1", "v2", "v3")):
            worst = max(worst, float(np.max(np.abs(got[u] - ref.y[i]))))
    assert worst <= 1e-5


# ----------------------------------------------------------------------------------------------
# the command line on the cluster (by its address)
# ----------------------------------------------------------------------------------------------
def test_pgd_query_into_a_file_on_the_cluster_equals_the_file_here(cluster, cross_here, tmp_path):
    import h5py

    cb_path = tmp_path / "predator_prey4.h5"
    cross_here.codebook.save(cb_path)
    rng = np.random.default_rng(5)
    with h5py.File(tmp_path / "points.h5", "w") as f:
        for c in cross_here.codebook.coordinates:
            f[c.name] = rng.uniform(*c.domain, size=70000)  # two partitions
    runner = CliRunner()
    base = ["query", str(cb_path), "--points", str(tmp_path / "points.h5")]
    here = runner.invoke(cli, base + ["--output", str(tmp_path / "here.h5")])
    there = runner.invoke(cli, base + ["--output", str(tmp_path / "there.h5"), "--scheduler",
                                       cluster.scheduler.address])
    assert here.exit_code == 0 and there.exit_code == 0, here.output + there.output
    assert here.stdout == "" and there.stdout == ""
    with h5py.File(tmp_path / "here.h5") as a, h5py.File(tmp_path / "there.h5") as b:
        for key in ("coordinates/t", "coordinates/x0", "values/x", "values/y"):
            assert np.array_equal(a[key][()], b[key][()])
        points = {c: a[f"coordinates/{c}"][()] for c in cross_here.codebook.coordinate_names}
        np.testing.assert_allclose(a["values/x"][()], cross_here.codebook.evaluate(points)["x"], rtol=0,
                                   atol=1e-15)


def test_pgd_verify_and_solve_on_the_cluster_by_its_address(cluster, tmp_path):
    runner = CliRunner()
    out = tmp_path / "parametric.h5"
    solved = runner.invoke(cli, ["solve", str(PROBLEMS / "parametric.yaml"), "-o", str(out), "--scheduler",
                                 cluster.scheduler.address, "--format", "json"])
    assert solved.exit_code == 0, solved.output
    assert "Dask: Dask cluster at tcp://" in solved.stderr
    checked = runner.invoke(cli, ["verify", str(out), "--format", "json"],
                            env={"PGD_SCHEDULER": cluster.scheduler.address})
    assert checked.exit_code == 0, checked.output
    assert '"cluster"' in checked.stdout


def test_an_unreachable_scheduler_is_one_error_line_before_any_work(monkeypatch, tmp_path):
    import pgdcli.cluster

    monkeypatch.setattr(pgdcli.cluster, "CONNECT_TIMEOUT", 0.5)
    out = tmp_path / "parametric.h5"
    result = CliRunner().invoke(cli, ["solve", str(PROBLEMS / "parametric.yaml"), "-o", str(out), "--scheduler",
                                      "tcp://127.0.0.1:9"])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: --scheduler tcp://127.0.0.1:9: cannot reach a Dask "
                                                   "scheduler there")
    assert not out.exists()


def test_a_scheduler_without_workers_is_refused(monkeypatch):
    import pgdcli.cluster

    monkeypatch.setattr(pgdcli.cluster, "CONNECT_TIMEOUT", 1.0)
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0") as empty:
        with pytest.raises(ClusterError, match="has no workers"):
            connect(empty.scheduler_address)


def test_workers_of_another_pgdcli_version_are_refused(cluster, monkeypatch):
    monkeypatch.setattr(pgdcli, "__version__", "0.0.0-elsewhere")
    with pytest.raises(ClusterError, match="runs pgdcli .*, this is 0.0.0-elsewhere"):
        connect(cluster.scheduler.address)


def test_a_local_cluster_closes_after_a_departure_it_never_saw_arrive():
    with local_cluster(1) as local:
        known = set(local.scheduler_info["workers"])
        local._update_worker_status("remove", "tcp://127.0.0.1:1")  # what a missed "add" leads to
        assert set(local.scheduler_info["workers"]) == known
    assert local.status.name == "closed"


def test_a_local_cluster_keeps_the_nanny_of_a_worker_slow_to_come_back():
    import dask

    # a lost-worker timeout of 0 s: any worker started again arrives too late for distributed's own
    # LocalCluster, which then closes its nanny (as a loaded machine does past 15 s)
    with dask.config.set({"distributed.deploy.lost-worker-timeout": "0s"}):
        with local_cluster(1) as local, distributed.Client(local) as client:
            [(address, pid)] = client.run(os.getpid).items()
            os.kill(pid, signal.SIGKILL)
            deadline = time.monotonic() + 300
            while time.monotonic() < deadline:
                workers = client.scheduler_info()["workers"]
                if (workers and address not in workers) or not local.workers:  # back, or its nanny closed
                    break
                time.sleep(0.1)
            assert workers and address not in workers  # the nanny started another worker
            assert [n.status.name for n in local.workers.values()] == ["running"]
            assert client.submit(os.getpid).result() not in (pid, os.getpid())
    assert local.status.name == "closed"
