"""``--scheduler`` and ``--workers``: the Dask cluster a command's independent tasks run on.

Without either (and without ``PGD_SCHEDULER``) a command runs as it always does, and Dask is not
imported. With one, :func:`open_executor` connects (or starts a ``LocalCluster``) before any work:
a scheduler that cannot be reached is one ``Error:`` line (exit 2), and the dashboard's link goes to
stderr.
"""

from __future__ import annotations

import contextlib

import click
from click.core import ParameterSource

from ..cluster import connect

__all__ = ["SCHEDULER_ENV", "cluster_options", "open_executor", "scheduler_given"]

SCHEDULER_ENV = "PGD_SCHEDULER"


def cluster_options(what: str):
    """The ``--scheduler`` and ``--workers`` options of a command, ``what`` naming the tasks."""

    def decorate(command):
        command = click.option(
            "--workers", type=click.IntRange(min=1), metavar="N",
            help=f"Start a local Dask cluster of N worker processes and run {what} on it (needs "
                 f"pip install 'pgdcli[dask]').")(command)
        return click.option(
            "--scheduler", metavar="ADDRESS", envvar=SCHEDULER_ENV, show_envvar=True,
            help=f"Run {what} on the Dask cluster whose scheduler is at ADDRESS (tcp://host:8786; see "
                 f"docs/cluster.md).")(command)

    return decorate


def scheduler_given(ctx: click.Context, scheduler: str | None) -> tuple[str | None, str]:
    """The scheduler's address (None when not given, or empty) and how it was named (for messages)."""
    if scheduler is not None and not scheduler.strip():
        scheduler = None
    source = ctx.get_parameter_source("scheduler")
    return scheduler, (SCHEDULER_ENV if source == ParameterSource.ENVIRONMENT else "--scheduler")


@contextlib.contextmanager
def open_executor(ctx: click.Context, scheduler: str | None, workers: int | None, quiet: bool = False):
    """The executor of ``--scheduler``/``--workers`` for the block (closed after it), or None.

    ``--workers`` given on the command line wins over a ``PGD_SCHEDULER`` of the environment; both
    given as options is a usage error.
    """
    address, option = scheduler_given(ctx, scheduler)
    if address is not None and workers is not None:
        if option == "--scheduler":
            raise click.UsageError("give --scheduler ADDRESS or --workers N, not both")
        address = None  # an explicit local cluster over the environment's scheduler
    if address is None and workers is None:
        yield None
        return
    executor = connect(address, workers, option=option)
    try:
        if not quiet:
            dashboard = executor.dashboard
            click.echo(f"Dask: {executor.description}" + (f"; dashboard {dashboard}" if dashboard else ""), err=True)
        yield executor
    finally:
        executor.close()
