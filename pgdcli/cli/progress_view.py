"""A solve's progress on stderr: a live bar on a terminal, plain lines at a modest rate elsewhere.

Both read the typed events of :mod:`pgdcli.progress` only (their phase, fraction and description),
so a new method or phase needs nothing here. Off a terminal (CI logs, ``2> log``, background runs)
a live bar would print nothing until the end: every phase change is a line, and the other events
are a line at most every :data:`PLAIN_EVERY` seconds. On a cluster, :meth:`count_tasks` adds the
count of the tasks it finished (a second bar, or a line at the same modest rate).
"""

from __future__ import annotations

import time

from ..progress import PhaseStarted

__all__ = ["solve_progress", "PLAIN_EVERY", "PlainProgress", "BarProgress"]

#: Seconds between two plain progress lines within a phase.
PLAIN_EVERY = 5.0

PHASES = {"solve": "solving", "check": "checking", "refine": "refining"}


def solve_progress(console, name: str):
    """The progress display of ``pgd solve``: a context manager whose value is the solve's callback."""
    return BarProgress(console, name) if console.is_terminal else PlainProgress(console, name)


class PlainProgress:
    """Plain progress lines: ``pgd solve NAME: checking: reference at 3/12 parameter points [41 s]``."""

    def __init__(self, console, name: str, every: float = PLAIN_EVERY, clock=time.monotonic):
        self.console, self.name, self.every, self.clock = console, name, every, clock
        self.started = self.last = self.tasks_last = clock()
        self.phase = ""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        return None

    def count_tasks(self, executor) -> None:
        """Tell the tasks ``executor`` (a :class:`pgdcli.executors.Executor`) finishes, a line at most every
        :attr:`every` seconds."""
        executor.progress = self._tasks

    def _tasks(self, done: int) -> None:
        now = self.clock()
        if now - self.tasks_last < self.every:
            return
        self.tasks_last = now
        self.console.print(f"pgd solve {self.name}: cluster: {done:,} tasks finished [{now - self.started:.0f} s]",
                           markup=False, highlight=False, soft_wrap=True)

    def __call__(self, event) -> None:
        now = self.clock()
        starts = isinstance(event, PhaseStarted)
        if not starts and now - self.last < self.every:
            return
        self.last = now
        self.phase = event.phase
        text = event.describe()
        fraction = event.fraction()
        share = f" ({100 * fraction:.0f}%)" if fraction is not None and not starts else ""
        self.console.print(f"pgd solve {self.name}: {PHASES.get(event.phase, event.phase)}: {text}{share} "
                           f"[{now - self.started:.0f} s]", markup=False, highlight=False, soft_wrap=True)


class BarProgress:
    """A rich progress bar: the phase, how far it is, and what it did last."""

    def __init__(self, console, name: str):
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        self.name = name
        columns = (TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.fields[status]}"),
                   TimeElapsedColumn())
        self.progress = Progress(*columns, console=console, transient=False)
        self.task = None

    def __enter__(self):
        self.progress.__enter__()
        self.task = self.progress.add_task(f"solving {self.name}", total=1.0, status="starting")
        return self

    def __exit__(self, *exc) -> None:
        self.progress.__exit__(*exc)

    def count_tasks(self, executor) -> None:
        """Show the tasks ``executor`` (a :class:`pgdcli.executors.Executor`) finishes, on a bar of their own."""
        tasks = self.progress.add_task("tasks on the cluster", total=None, status="")
        executor.progress = lambda done: self.progress.update(tasks, status=f"{done:,} finished")

    def __call__(self, event) -> None:
        fields = {"status": event.describe()}
        if isinstance(event, PhaseStarted):
            fields["description"] = f"{PHASES.get(event.phase, event.phase)} {self.name}"
        fraction = event.fraction()
        if fraction is not None:
            fields["completed"] = fraction
        self.progress.update(self.task, **fields)
