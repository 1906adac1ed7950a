"""``pgd fit`` (:mod:`pgdcli.inference`) and ``pgd export`` (:mod:`pgdcli.codebook.export`)."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import click

from .formats import FIT
from .group import Failed, cli, format_option


@FIT.register("plain", "'name estimate stderr' per free coordinate")
def write_estimate(stream, result) -> None:
    """One line per free coordinate, ``name estimate stderr`` (full precision)."""
    for name, value in result.estimate.items():
        stream.write(f"{name} {value!r} {result.stderr[name]!r}\n")


@FIT.register("csv", "the fitted curve")
def write_curve(stream, result) -> None:
    """The fitted curve, one row per data row: the data's coordinate columns, then for every unknown
    its fitted value and, when observed, ``<u>_data``."""
    columns, values = [], []
    for name, col in result.fitted.items():
        columns.append(name)
        values.append(col)
        if name in result.data:
            columns.append(f"{name}_data")
            values.append(result.data[name])
    writer = csv.writer(stream, lineterminator="\n")
    writer.writerow(columns)
    for row in zip(*values):
        writer.writerow([repr(float(v)) for v in row])


@FIT.register("json", "everything")
def write_everything(stream, result) -> None:
    """:meth:`~pgdcli.inference.fitting.FitResult.to_dict` as JSON."""
    stream.write(json.dumps(result.to_dict(), indent=2) + "\n")


def _assignments(values, option: str) -> dict:
    """``NAME=VALUE`` options (repeatable, or comma lists) -> {name: float}."""
    out = {}
    for text in values:
        for item in filter(None, (p.strip() for p in text.split(","))):
            name, sep, value = item.partition("=")
            try:
                out[name.strip()] = float(value)
            except ValueError:
                sep = ""
            if not sep or not name.strip():
                raise click.BadParameter(f"expected NAME=VALUE, got {item!r}", param_hint=f"'{option}'")
    return out


@cli.command("fit")
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("data", type=click.File("r"))
@click.option("--fix", multiple=True, metavar="NAME=V[,NAME=V]", help="Hold coordinates at values (repeatable).")
@click.option("--sigma", multiple=True, metavar="U=S[,U=S]",
              help="Standard deviation of an observed unknown's data (default 1; a sigma_U column: per row).")
@click.option("--starts", type=click.IntRange(min=1), default=8, show_default=True, metavar="N",
              help="Local solves: the box centre, then N-1 scrambled Sobol points.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Sobol scrambling seed.")
@click.option("--no-check", is_flag=True, help="Skip the re-solve at the estimate by the independent reference.")
@format_option(FIT)
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False, path_type=Path), metavar="FILE.png",
              help="Draw the data and the fit (.png or .svg).")
@click.option("-q", "--quiet", is_flag=True, help="No summary line on stderr.")
def fit_command(codebook, data, fix, sigma, starts, seed, no_check, fmt, plot_path, quiet):
    """Estimate the free coordinates of CODEBOOK that best explain DATA (CSV, '-' for stdin).

    \b
    DATA's header names known coordinates (the time coordinate at least), observed
    unknowns (a subset is fine) and optional sigma_<unknown> columns. Every other
    coordinate not held by --fix is estimated within its domain (least squares,
    Jacobian from the codebook's exact derivatives), then checked by re-solving at
    the estimate with the independent reference.

    Exit status: 0 success; 1 an estimate on a bound of its domain (the best
    fit may lie outside the codebook: one Warning line, the output is still
    written, "success": false) or a least-squares solve that did not
    converge; 2 invalid input.

    \b
      pgd fit codebooks/coupled.h5 trajectory.csv --sigma u1=1e-3 --format json
    """
    from ..inference.fitting import fit
    from ..inference.report import plot_fit, summary

    if plot_path is not None:
        from ..plot.options import require_matplotlib

        require_matplotlib("pgd fit --plot")  # before the fit
    label = "DATA (stdin)" if data.name == "<stdin>" else str(data.name)
    result = fit(codebook, data, fix=_assignments(fix, "--fix"), sigma=_assignments(sigma, "--sigma"),
                 starts=starts, seed=seed, check=not no_check, label=label)
    FIT.writer(fmt)(sys.stdout, result)
    if plot_path is not None:
        plot_fit(result, plot_path)
    if not quiet:
        click.echo(summary(result), err=True)
    if result.at_bound:
        where = ", ".join(f"{n} = {result.estimate[n]:.6g} (domain [{result.bounds[n][0]:g}, "
                          f"{result.bounds[n][1]:g}])" for n in result.at_bound)
        raise Failed(f"fit: the estimate lies on its domain bound: {where}; the best fit may lie outside the "
                     f"codebook: widen the domain and solve again", warning=True)
    if not result.success:
        raise Failed(f"fit: least squares did not converge: {result.message}")


@cli.command("export")
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--to", "target", type=click.Choice(["c", "glsl", "json"]), required=True,
              help="c: one C99 header (double and float32 evaluators); glsl: a shader function; json: the numbers.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), metavar="FILE",
              help="Write to FILE [default: stdout].")
@click.option("--force", is_flag=True, help="Export even past the size limit (16 MiB of float64 numbers).")
@click.option("-q", "--quiet", is_flag=True, help="No size line on stderr.")
@click.option("--event", metavar="NAME", help="Export the time of this event instead of the unknowns: an "
                                              "evaluator of the coordinates other than time.")
def export_command(codebook, target, output, force, quiet, event):
    """Write a self-contained evaluator of CODEBOOK for engines and other languages.

    \b
      pgd export codebooks/rigid_body.h5 --to c -o pgd_rigid_body.h
      pgd export codebooks/coupled.h5 --to json > coupled.json
      pgd export codebooks/landing.h5 --event landing --to c -o pgd_landing_landing.h
    """
    from ..codebook.codebook import Codebook
    from ..codebook.export import export

    cb = Codebook.load(codebook, evaluation_only=True)
    if event is not None:
        cb = cb.event_codebook(event)
    files, size = export(cb, target, force=force)
    ((name, text),) = files.items()
    if output is None:
        sys.stdout.write(text)
    else:
        from ..codebook.io import write_atomic

        write_atomic(output, text, what="the export")
    if not quiet:
        where = output if output is not None else f"stdout ({name})"
        click.echo(f"exported {cb.name} to {target}: {size // 8} numbers, {size / 2**20:.2f} MiB as float64; "
                   f"{len(text.encode()) / 2**20:.2f} MiB of text to {where}", err=True)
