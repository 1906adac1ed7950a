"""``pgd plot``: figures of a codebook (:mod:`pgdcli.plot`)."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import TimeBudgetExceeded
from ..limits import DEFAULT_CHECK_SECONDS
from .group import Failed, cli
from .outputs import prepare_output
from .sensitivity_command import parse_densities


@cli.command("plot")
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--kind", type=click.Choice(["solution", "modes", "convergence", "error", "phase", "sensitivity"]),
              help="What to draw [default: solution; modes with --count, phase with --x/--y, sensitivity "
                   "with --density].")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Image file, .png or .svg [default: <codebook dir>/<codebook stem>-<kind>.png].")
@click.option("--field", metavar="NAME", help="Unknown to draw [default: the first].")
@click.option("--count", type=int, metavar="N", help="modes: how many modes per coordinate [default: 6].")
@click.option("--at", "at", multiple=True, metavar="NAME=V[,NAME=V]",
              help="solution/error/phase: a curve along time at this point (repeatable); unset non-time "
                   "coordinates take their domain midpoints. sensitivity: coordinates held fixed.")
@click.option("--x", "x", metavar="NAME", help="phase: the unknown along the horizontal axis, or der(NAME) its rate "
                                                 "[default: the first unknown].")
@click.option("--y", "y", metavar="NAME", help="phase: the unknown along the vertical axis, or der(NAME) [default: "
                                                 "the second unknown, or the rate of the first].")
@click.option("--density", "density", multiple=True, metavar="NAME=SPEC",
              help="sensitivity: an input's density, uniform:LOW,HIGH or normal:MEAN,SD (repeatable).")
@click.option("--over", metavar="X,Y", help="solution/error: a heat map with X along x and Y along y.")
@click.option("--fix", multiple=True, metavar="NAME=V[,NAME=V]",
              help="With --over: values of the other coordinates [default: domain midpoints].")
@click.option("--reference", is_flag=True,
              help="solution/phase: draw the independent reference (solve_ivp) on top, as markers or dashed contours.")
@click.option("--points", type=int, metavar="N", help="Samples per curve [201] or per map axis [81].")
@click.option("--dpi", type=int, default=150, show_default=True, metavar="N", help="PNG resolution (dots per inch).")
@click.option("--size", metavar="WxH", help="Figure size in inches, e.g. 8x5 [default: per kind].")
@click.option("--max-seconds", type=click.FloatRange(min=0, min_open=True), default=DEFAULT_CHECK_SECONDS,
              show_default=True, metavar="S",
              help="Time budget of the reference integrations (--reference, --kind error): past it nothing is "
                   "written and the exit status is 1.")
def plot_command(codebook, kind, output, field, count, at, x, y, density, over, fix, reference, points, dpi, size,
                 max_seconds):
    """Draw CODEBOOK's solution, modes, convergence, error, phase portrait or sensitivity as a PNG or SVG.

    Prints the path of the written image on stdout.

    \b
      pgd plot codebooks/spring.h5                        # solution: curves along time
      pgd plot codebooks/spring.h5 --kind modes           # the first 6 modes per coordinate
      pgd plot codebooks/spring.h5 --kind convergence -o conv.svg
      pgd plot codebooks/drag.h5 --kind phase --x x --y y --at a=0.4 --at a=0.8
      pgd plot codebooks/pendulum.h5 --kind sensitivity --field th
      pgd plot codebooks/spring.h5 --kind solution --at k=1.5 --at k=3,c=0.1 --reference
      pgd plot codebooks/spring.h5 --kind solution --over t,k --fix c=0.2
      pgd plot codebooks/spring.h5 --kind error --over k,c --fix t=4
    """
    from ..plot import files as plotting
    from ..plot.options import require_matplotlib
    require_matplotlib("pgd plot")  # before any file or folder is made
    if kind is None:  # what the options given ask for, else the solution
        kind = ("modes" if count is not None else "phase" if x is not None or y is not None
                else "sensitivity" if density else "solution")
    target = Path(output) if output is not None else plotting.default_output(codebook, kind)
    prepare_output(target, "--output", suffixes=(".png", ".svg"))  # before the plot is computed
    try:
        path = plotting.render(codebook, kind, target, field=field, count=count, at=at, over=over, fix=fix,
                               reference=reference, points=points, dpi=dpi, size=size, max_seconds=max_seconds,
                               x=x, y=y, densities=parse_densities(density),
                               warn=lambda message: click.echo(f"Warning: {message}", err=True))
    except TimeBudgetExceeded as exc:
        raise Failed(str(exc)) from None
    click.echo(str(path))
