"""``pgd sensitivity``: means, variances and Sobol indices of a codebook (:mod:`pgdcli.codebook.sensitivity`)."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import click

from ..errors import QueryError
from .formats import SENSITIVITY
from .group import cli, format_option
from .query import UsageProblem, parse_values


def _at(values, cb) -> dict:
    """Repeatable ``--at NAME=V[,NAME=V]`` -> {name: value}, checked against the codebook."""
    from ..plot.options import parse_point

    out: dict = {}
    for text in values:
        for name, value in parse_point(text, cb, "--at").items():
            if name in out:
                raise QueryError(f"--at: coordinate {name!r} given twice")
            out[name] = value
    return out


def parse_densities(values) -> dict:
    """Repeatable ``--density NAME=SPEC`` -> {name: SPEC text}."""
    out = {}
    for text in values:
        name, sep, spec = text.partition("=")
        if not sep or not name.strip() or not spec.strip():
            raise click.BadParameter(f"expected NAME=SPEC (uniform, uniform:LOW,HIGH or normal:MEAN,SD), got {text!r}",
                                     param_hint="'--density'")
        if name.strip() in out:
            raise click.BadParameter(f"coordinate {name.strip()!r} given twice", param_hint="'--density'")
        out[name.strip()] = spec.strip()
    return out


@SENSITIVITY.register("plain", "an aligned table (6 digits)")
def write_table(stream, result) -> None:
    """A header and one aligned row per (unknown, time), 6 digits."""
    header, rows = _columns(result)
    cells = [header] + [[v if isinstance(v, str) else f"{v:.6g}" for v in row.values()] for row in rows]
    widths = [max(len(r[k]) for r in cells) for k in range(len(header))]
    for r in cells:
        stream.write("  ".join(c.ljust(w) if k == 0 else c.rjust(w) for k, (c, w) in enumerate(zip(r, widths))).rstrip()
                     + "\n")


@SENSITIVITY.register("csv", "the same columns, full precision")
def write_csv(stream, result) -> None:
    """The plain table's columns, one row per (unknown, time), at full precision."""
    header, rows = _columns(result)
    writer = csv.writer(stream, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([v if isinstance(v, str) else repr(v) for v in row.values()])


@SENSITIVITY.register("json", "everything")
def write_json(stream, result) -> None:
    """:meth:`~pgdcli.codebook.sensitivity.SensitivityResult.to_dict` as JSON."""
    stream.write(json.dumps(result.to_dict(), indent=2) + "\n")


def _columns(result) -> tuple[list, list]:
    """The table's header and its rows (:meth:`~pgdcli.codebook.sensitivity.SensitivityResult.rows`)."""
    rows = result.rows()
    return (list(rows[0]) if rows else ["unknown"]), rows


@cli.command("sensitivity")
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--at", "at", multiple=True, metavar="NAME=V[,NAME=V]",
              help="Hold coordinates fixed (repeatable); every space coordinate must be.")
@click.option("--times", metavar="VALUES", help="Times: a number, a comma list or start:stop:count [default: 11 over "
                                                 "the time domain].")
@click.option("--density", "density", multiple=True, metavar="NAME=SPEC",
              help="An input's density: uniform (default), uniform:LOW,HIGH or normal:MEAN,SD (truncated to the "
                   "domain); repeatable.")
@click.option("--second-order", is_flag=True, help="Also the second-order index of every pair of inputs.")
@click.option("--field", "fields", multiple=True, metavar="NAME", help="Unknown (repeatable) [default: all].")
@format_option(SENSITIVITY)
@click.option("-q", "--quiet", is_flag=True, help="No summary line on stderr.")
def sensitivity_command(codebook, at, times, density, second_order, fields, fmt, quiet):
    """Mean, variance and Sobol indices of CODEBOOK's unknowns over its parameters.

    \b
    Every coordinate that is neither time nor held by --at is a random input,
    uniform over its domain unless --density says otherwise. For each unknown
    and time: its mean and variance over the inputs, and each input's
    first-order index (the share of the variance it explains alone) and total
    index (alone and with others). They are computed exactly from the
    codebook's separated form by one-dimensional quadratures: no sampling.

    \b
      pgd sensitivity codebooks/pendulum.h5 --times 0:3:7
      pgd sensitivity codebooks/heat1d.h5 --at x=0.5 --format csv
      pgd sensitivity codebooks/drag.h5 --density k=normal:0.02,0.005 --second-order --format json
    """
    from ..codebook.codebook import Codebook
    cb = Codebook.load(codebook)
    values = None
    if times is not None:
        tc = next((c for c in cb.coordinates if c.role == "time"), None)
        try:
            values = parse_values(tc.name if tc is not None else "times", times)
        except UsageProblem as exc:
            raise click.BadParameter(exc.message.replace(f"'--{tc.name if tc else 'times'}'", ""),
                                     param_hint="'--times'") from None
    result = cb.sensitivity(times=values, at=_at(at, cb), densities=parse_densities(density), second_order=second_order,
                            fields=list(fields) or None)
    SENSITIVITY.writer(fmt)(sys.stdout, result)
    if not quiet:
        where = f" at {len(result.times)} times" if result.time is not None else ""
        click.echo(f"sensitivity: {len(result.unknowns)} unknown(s), {len(result.inputs)} input(s) "
                   f"({', '.join(result.inputs) or 'none'}){where}, in {1e3 * result.seconds:.1f} ms "
                   f"(exact quadrature of the codebook)", err=True)
