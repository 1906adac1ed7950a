"""``pgd query`` through click (help, errors, --points); a plain query runs in :mod:`pgdcli.cli.query`."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from . import stream  # registers the query's output formats
from .formats import QUERY
from .group import cli, format_option

@cli.command(context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@format_option(QUERY)
@click.option("--field", "fields", multiple=True, metavar="NAME",
              help="Unknown to print (repeatable) [default: all, in declared order].")
@click.option("--points", metavar="FILE",
              help="CSV file whose header names the coordinates ('-' for stdin): one output row per input row, "
                   "read and printed in chunks.")
@click.pass_context
def query(ctx, codebook, fmt, fields, points):
    """Evaluate CODEBOOK at points given as --NAME VALUE for every coordinate.

    \b
    VALUE is a number, a comma list (0.1,0.2,0.5) or start:stop:count
    (0:1:11). Lists give the cartesian product of all coordinates, the first
    coordinate varying slowest. Values are printed with full float64
    precision.

    \b
      pgd query codebooks/parametric.h5 --t 5 --k 2
      pgd query codebooks/spring.h5 --t 0:4:41 --k 2 --c 0.3 --field x --format csv
    """
    # the parsing, checking and printing helpers live in pgdcli.cli.query and pgdcli.cli.stream, where a
    # plain `pgd query` runs without click (see main): both paths print the same bytes
    from . import query as _query
    from ..codebook.codebook import Codebook

    cb = Codebook.load(codebook, evaluation_only=True)
    selected = list(fields) if fields else cb.unknown_names
    for f in selected:
        if f not in cb.fields:
            raise click.BadParameter(f"unknown field {f!r}; this codebook has {', '.join(cb.unknown_names)}",
                                     param_hint="'--field'")
    if points is not None and ctx.args:
        raise click.UsageError("give either --points FILE or --NAME VALUE options, not both")
    try:
        chunks, handle = _query.point_chunks(cb, points, ctx.args)
    except _query.UsageProblem as exc:
        if exc.param_hint is not None:
            raise click.BadParameter(exc.message, param_hint=exc.param_hint) from None
        raise click.UsageError(exc.message) from None
    try:
        stream.Writer(sys.stdout, fmt, cb, selected).run(chunks)
    finally:
        if handle is not None:
            handle.close()
