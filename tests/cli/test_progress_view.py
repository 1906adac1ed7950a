"""pgd solve's progress on stderr: plain lines at a modest rate off a terminal, a live bar on one."""

from __future__ import annotations

import io

from click.testing import CliRunner
from conftest import PROBLEMS
from rich.console import Console

from pgdcli.cli.main import cli
from pgdcli.executors import SerialExecutor
from pgdcli.cli.progress_view import BarProgress, PlainProgress, solve_progress
from pgdcli.progress import MarchStep, PhaseStarted, ReferenceProgress


class _Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_plain_lines_at_every_phase_and_at_most_every_few_seconds_between():
    out = io.StringIO()
    clock = _Clock()
    show = PlainProgress(Console(file=out, width=200), "drag", every=5.0, clock=clock)
    show(PhaseStarted("solve", "march to RMS 7e-07", 1))
    for k in range(1, 13):  # a step a second
        clock.now = float(k)
        show(MarchStep(k / 12, 1.0, k, []))
    show(PhaseStarted("check", "error gate against scipy's DOP853", 1))  # a phase change is always a line
    clock.now = 12.5
    show(ReferenceProgress(0.5, 1.0, "time"))  # within 5 s of the last line: none
    lines = out.getvalue().splitlines()
    assert lines == ["pgd solve drag: solving: march to RMS 7e-07 [0 s]",
                     "pgd solve drag: solving: t = 0.4167/1, 5 steps (42%) [5 s]",
                     "pgd solve drag: solving: t = 0.8333/1, 10 steps (83%) [10 s]",
                     "pgd solve drag: checking: error gate against scipy's DOP853 [12 s]"]


def test_plain_lines_count_the_tasks_a_cluster_finished_at_a_modest_rate():
    out = io.StringIO()
    clock = _Clock()
    show = PlainProgress(Console(file=out, width=200), "chain", every=5.0, clock=clock)
    executor = SerialExecutor()
    show.count_tasks(executor)

    def task(k):
        clock.now = float(k)  # a task a second
        return k

    assert list(executor.map(task, range(1, 13))) == list(range(1, 13))
    assert out.getvalue().splitlines() == ["pgd solve chain: cluster: 5 tasks finished [5 s]",
                                           "pgd solve chain: cluster: 10 tasks finished [10 s]"]


def test_a_bar_on_a_terminal_counts_the_tasks_a_cluster_finished():
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=120)
    executor = SerialExecutor()
    with solve_progress(console, "chain") as show:
        show.count_tasks(executor)
        list(executor.map(abs, range(1234)))
    assert "tasks on the cluster" in out.getvalue() and "1,234 finished" in out.getvalue()


def test_a_bar_on_a_terminal():
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=120)
    with solve_progress(console, "drag") as show:
        assert isinstance(show, BarProgress)
        show(PhaseStarted("check", "error gate against scipy's DOP853", 1))
        show(ReferenceProgress(1.0, 2.0, "time"))
    assert "checking drag" in out.getvalue() and "reference at 50% of the time domain" in out.getvalue()
    assert isinstance(solve_progress(Console(file=io.StringIO()), "drag"), PlainProgress)


def test_solve_off_a_terminal_prints_its_phases_on_stderr_and_nothing_on_stdout(tmp_path):
    res = CliRunner().invoke(cli, ["solve", str(PROBLEMS / "drag.yaml"), "-o", str(tmp_path / "drag.h5")])
    assert res.exit_code == 0, res.output
    assert res.stdout == ""
    lines = [line for line in res.stderr.splitlines() if line.startswith("pgd solve drag: ")]
    assert lines[0].startswith("pgd solve drag: solving: method march (equations nonlinear")
    assert any(line.startswith("pgd solve drag: checking: error gate against scipy's DOP853") for line in lines)
    assert any(line.startswith("pgd solve drag: solving: pilot march along k: 33 nodes") for line in lines)
    assert any(line.startswith("pgd solve drag: refining: first nodes from the pilot: k ") for line in lines)
    quiet = CliRunner().invoke(cli, ["solve", str(PROBLEMS / "drag.yaml"), "-o", str(tmp_path / "q.h5"), "-q"])
    assert quiet.exit_code == 0 and quiet.stderr == "" and quiet.stdout == ""
