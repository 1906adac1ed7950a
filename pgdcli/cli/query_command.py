"""``pgd query`` through click (help, errors, --points); a plain query runs in :mod:`pgdcli.cli.query`."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from . import query as _query
from . import stream  # registers the query's output formats
from .cluster_options import cluster_options, open_executor, scheduler_given
from ..errors import QueryError
from .formats import QUERY
from .group import cli, format_option, stderr_console, warn
from .outputs import prepare_output


@cli.command(context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@format_option(QUERY)
@click.option("--field", "fields", multiple=True, metavar="NAME",
              help="Unknown to print (repeatable) [default: all, in declared order].")
@click.option("--points", metavar="FILE",
              help="CSV file whose header names the coordinates ('-' for stdin): one output row per input row, "
                   "read and printed in chunks.")
@click.option("--output", type=click.Path(dir_okay=False, path_type=Path), metavar="FILE.h5",
              help="Write the points and values to this HDF5 file (atomically) instead of stdout, evaluated in "
                   "partitions; --points may then be an HDF5 file too (docs/cluster.md).")
@click.option("--event", "events", multiple=True, metavar="NAME",
              help="Print the time of this event (repeatable) instead of the unknowns: the first time its "
                   "condition is met, given the coordinates other than time.")
@cluster_options("the partitions of an --output query")
@click.pass_context
def query(ctx, codebook, fmt, fields, points, output, events, scheduler, workers):
    """Evaluate CODEBOOK at points given as --NAME VALUE for every coordinate.

    \b
    VALUE is a number, a comma list (0.1,0.2,0.5) or start:stop:count
    (0:1:11). Lists give the cartesian product of all coordinates, the first
    coordinate varying slowest. Values are printed with full float64
    precision.

    \b
      pgd query codebooks/parametric.h5 --t 5 --k 2
      pgd query codebooks/spring.h5 --t 0:4:41 --k 2 --c 0.3 --field x --format csv
      pgd query codebooks/spring.h5 --points big.h5 --output values.h5 --workers 2
      pgd query codebooks/ball.h5 --event landing --v0 8 --c 0.1
    """
    # the parsing, checking and printing helpers live in pgdcli.cli.query and pgdcli.cli.stream, where a
    # plain `pgd query` runs without click (see main): both paths print the same bytes
    from ..codebook.codebook import Codebook

    cb = Codebook.load(codebook, evaluation_only=True)
    if events:
        return _events(ctx, cb, fmt, fields, points, output, list(events))
    selected = list(fields) if fields else cb.unknown_names
    for f in selected:
        if f not in cb.fields:
            raise click.BadParameter(f"unknown field {f!r}; this codebook has {', '.join(cb.unknown_names)}",
                                     param_hint="'--field'")
    if points is not None and ctx.args:
        raise click.UsageError("give either --points FILE or --NAME VALUE options, not both")
    if output is None and (workers is not None or scheduler_given(ctx, scheduler)[1] == "--scheduler" and scheduler):
        # PGD_SCHEDULER alone leaves a query to stdout here: it evaluates each point on its own
        raise click.UsageError("--scheduler and --workers evaluate into --output FILE.h5; add --output")
    if output is not None and ctx.get_parameter_source("fmt") != click.core.ParameterSource.DEFAULT:
        raise click.UsageError(f"--format {fmt} prints to stdout; --output writes HDF5: give one of them")
    ended = _Ended(cb) if getattr(cb, "action", None) == "terminal" else None
    if ended is not None and points is None:
        ended.refuse_one(_usage(_query.grid_axes, ctx.args, cb))
    if output is not None:
        return _to_file(ctx, cb, points, output, selected, scheduler, workers)
    chunks, handle = _usage(_query.point_chunks, cb, points, ctx.args)
    try:
        stream.Writer(sys.stdout, fmt, cb if ended is None else ended, selected).run(chunks)
    finally:
        if handle is not None:
            handle.close()
    if ended is not None and ended.count:
        warn(f"{ended.count} of {ended.total} points are at or after the terminal event {cb.acting!r}: the motion "
             f"has ended there and their values are NaN")


class _Ended:
    """A codebook with a terminal event, counting the points evaluated after it (the rest as the codebook)."""

    def __init__(self, cb):
        self.cb, self.count, self.total = cb, 0, 0

    def __getattr__(self, name):
        return getattr(self.cb, name)

    def evaluate(self, coordinates, fields=None):
        self.total += 1
        self.count += bool(self.cb.ended(coordinates))
        return self.cb.evaluate(coordinates, fields)

    def refuse_one(self, axes: list) -> None:
        """One point after the event: an error naming the event's time (a grid of several gets NaN rows)."""
        if any(len(a) != 1 for a in axes):
            return
        point = {c.name: float(a[0]) for c, a in zip(self.cb.coordinates, axes)}
        if not self.cb.ended(point):
            return
        time = next(c.name for c in self.cb.coordinates if c.role == "time")
        params = {n: v for n, v in point.items() if n != time}
        at = float(self.cb.event_times(params, [self.cb.acting])[self.cb.acting])
        where = ", ".join(f"{n}={v:g}" for n, v in params.items())
        raise QueryError(f"{time}={point[time]:g} is at or after the terminal event {self.cb.acting!r} at "
                               f"{time}={at:.10g}{' (' + where + ')' if where else ''}: the motion has ended there")


def _events(ctx, cb, fmt, fields, points, output, events: list[str]) -> None:
    """``--event NAME``: the events' times at the points, printed as the unknowns would be."""
    if fields:
        raise click.UsageError("--field selects unknowns and --event prints event times: give one of them")
    if output is not None:
        raise click.UsageError("--event prints to stdout; --output writes the unknowns: give one of them")
    if points is not None and ctx.args:
        raise click.UsageError("give either --points FILE or --NAME VALUE options, not both")
    view = _usage(_query.EventView, cb, events)
    chunks, handle = _usage(_query.point_chunks, view, points, ctx.args)
    try:
        stream.Writer(sys.stdout, fmt, view, events).run(chunks)
    finally:
        if handle is not None:
            handle.close()


def _usage(function, *args):
    """``function(*args)``, its usage problems as click's."""
    try:
        return function(*args)
    except _query.UsageProblem as exc:
        if exc.param_hint is not None:
            raise click.BadParameter(exc.message, param_hint=exc.param_hint) from None
        raise click.UsageError(exc.message) from None


def _to_file(ctx, cb, points, output, selected, scheduler, workers) -> None:
    """``--output``: the points evaluated in partitions (on the cluster, if one is given) into an HDF5 file."""
    from .query_output import H5_SUFFIXES, point_partitions, write_query

    prepare_output(output, "--output", H5_SUFFIXES)
    chunks, handle = _usage(point_partitions, cb, points, ctx.args)
    try:
        with open_executor(ctx, scheduler, workers) as executor:
            written = write_query(cb, chunks, output, selected, executor, stderr_console())
    finally:
        if handle is not None:
            handle.close()
    if getattr(cb, "action", None) == "terminal" and selected:
        ended = _nan_rows(output, selected[0])
        if ended:
            warn(f"{ended} of {written} points are at or after the terminal event {cb.acting!r}: the motion has "
                 f"ended there and their values in {output} are NaN")


def _nan_rows(path, field: str) -> int:
    """Rows of ``values/field`` in a query's HDF5 output that are NaN, read a block at a time."""
    import h5py
    import numpy as np

    block = 1 << 20
    with h5py.File(path, "r") as f:
        values = f["values"][field]
        return sum(int(np.isnan(values[i:i + block]).sum()) for i in range(0, values.shape[0], block))
