"""``pgd plot``: figures of a codebook (:mod:`pgdcli.plot`)."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import TimeBudgetExceeded
from ..limits import DEFAULT_CHECK_SECONDS
from .group import Failed, cli

@cli.command("plot")
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--kind", type=click.Choice(["modes", "convergence", "solution", "error"]), default="modes",
              show_default=True, help="What to draw.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Image file, .png or .svg [default: <codebook dir>/<codebook stem>-<kind>.png].")
@click.option("--field", metavar="NAME", help="Unknown to draw [default: the first].")
@click.option("--count", type=int, metavar="N", help="modes: how many modes per coordinate [default: 6].")
@click.option("--at", "at", multiple=True, metavar="NAME=V[,NAME=V]",
              help="solution/error: a curve along time at this point (repeatable); unset non-time "
                   "coordinates take their domain midpoints.")
@click.option("--over", metavar="X,Y", help="solution/error: a heat map with X along x and Y along y.")
@click.option("--fix", multiple=True, metavar="NAME=V[,NAME=V]",
              help="With --over: values of the other coordinates [default: domain midpoints].")
@click.option("--reference", is_flag=True,
              help="solution: draw the independent reference (solve_ivp) on top, as markers or dashed contours.")
@click.option("--points", type=int, metavar="N", help="Samples per curve [201] or per map axis [81].")
@click.option("--dpi", type=int, default=150, show_default=True, metavar="N", help="PNG resolution (dots per inch).")
@click.option("--size", metavar="WxH", help="Figure size in inches, e.g. 8x5 [default: per kind].")
@click.option("--max-seconds", type=click.FloatRange(min=0, min_open=True), default=DEFAULT_CHECK_SECONDS,
              show_default=True, metavar="S",
              help="Time budget of the reference integrations (--reference, --kind error): past it nothing is "
                   "written and the exit status is 1.")
def plot_command(codebook, kind, output, field, count, at, over, fix, reference, points, dpi, size, max_seconds):
    """Draw CODEBOOK's modes, convergence, solution or error as a PNG or SVG.

    Prints the path of the written image on stdout.

    \b
      pgd plot codebooks/spring.h5                        # modes: the first 6 per coordinate
      pgd plot codebooks/spring.h5 --kind convergence -o conv.svg
      pgd plot codebooks/spring.h5 --kind solution --at k=1.5 --at k=3,c=0.1 --reference
      pgd plot codebooks/spring.h5 --kind solution --over t,k --fix c=0.2
      pgd plot codebooks/spring.h5 --kind error --over k,c --fix t=4
    """
    from ..plot import files as plotting
    from .outputs import prepare_output

    target = Path(output) if output is not None else plotting.default_output(codebook, kind)
    prepare_output(target, "--output", suffixes=(".png", ".svg"))  # before the plot is computed
    try:
        path = plotting.render(codebook, kind, target, field=field, count=count, at=at, over=over, fix=fix,
                               reference=reference, points=points, dpi=dpi, size=size, max_seconds=max_seconds,
                               warn=lambda message: click.echo(f"Warning: {message}", err=True))
    except TimeBudgetExceeded as exc:
        raise Failed(str(exc)) from None
    click.echo(str(path))
