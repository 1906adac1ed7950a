"""The ``pgd`` command line: a thin layer over the library.

Each command parses its options, calls one library function and formats the
result. stdout carries data only; progress, tables and messages go to stderr.
Exit status: 0 success, 1 a numerical outcome the user asked to be told
about (solver not converged, verification gate failed), 2 invalid input
(one ``Error:`` line, no traceback), 70 an internal error (a bug: one line,
the traceback with ``--debug``); see :mod:`pgdcli.cli.guard`.

This is the only module that imports click and rich; rich is imported only by
the commands that draw with it, so ``pgd query`` stays lean.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import click

from .. import __version__
from . import guard
from ..errors import PgdError
from .guard import EXIT_FAILED, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE


# ----------------------------------------------------------------------------------------------
# one-line errors for every usage problem
# ----------------------------------------------------------------------------------------------
class PgdGroup(click.Group):
    """A click group that runs every command inside the guard of :mod:`pgdcli.cli.guard`.

    Usage errors and :class:`PgdError` are one ``Error:`` line on stderr (exit 2);
    anything unexpected is one ``Error: internal error: ...`` line (exit 70, the
    traceback with ``--debug`` or ``PGD_DEBUG=1``); a reader gone away ends the
    command quietly (exit 0) and a full disk is one line (exit 2). Never a traceback.
    """

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        try:
            code = super().main(args=args, prog_name=prog_name or "pgd", complete_var=complete_var,
                                standalone_mode=False, **extra)
            code = _flushed(code)
        except click.exceptions.NoArgsIsHelpError as exc:  # bare `pgd`: show the help
            click.echo(exc.ctx.get_help() if exc.ctx else "")
            code = EXIT_OK
        except click.UsageError as exc:
            hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
            _error(exc.format_message() + hint)
            code = EXIT_USAGE
        except PgdError as exc:
            _error(str(exc))
            code = EXIT_USAGE
        except click.ClickException as exc:
            _error(exc.format_message())
            code = exc.exit_code
        except click.Abort:
            _error("aborted")
            code = EXIT_FAILED
        except KeyboardInterrupt:
            _error("interrupted")
            code = EXIT_INTERRUPTED
        except _Failed as exc:
            code = _flushed(EXIT_FAILED)
            if code != EXIT_USAGE:  # a full disk was reported instead; a reader gone away is no excuse
                _error(str(exc))
                code = EXIT_FAILED
        except BrokenPipeError:
            code = _flushed(EXIT_OK, broken=True)
        except Exception as exc:  # noqa: BLE001 - the guard: nothing escapes as a traceback
            code = _unexpected(exc)
        if not isinstance(code, int):
            code = EXIT_OK
        if guard.flush_stdout() is not None:  # after an error: no second report, no failing flush at exit
            guard.silence_stdout()
        if standalone_mode:
            sys.exit(code)
        return code


def _flushed(code, broken: bool = False):
    """Flush stdout inside the guard: a reader gone away ends quietly (exit 0), a full disk is one line."""
    exc = None if broken else guard.flush_stdout()
    if broken or isinstance(exc, BrokenPipeError):
        # a pipeline reader went away (e.g. `pgd query ... | head`): not an error
        guard.silence_stdout()
        return EXIT_OK
    if exc is not None:
        guard.silence_stdout()
        _error(guard.output_error_message(exc, "to stdout"))
        return EXIT_USAGE
    return code


def _unexpected(exc: Exception) -> int:
    """An exception nobody meant to raise: a full disk (exit 2) or a bug (exit 70)."""
    if guard.is_output_error(exc):
        guard.silence_stdout()
        _error(guard.output_error_message(exc, getattr(exc, "filename", None) or "to stdout"))
        return EXIT_USAGE
    if guard.debug_enabled():
        import traceback

        traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)
    _error(guard.internal_error_message(exc))
    return EXIT_INTERNAL


def _warn(message: str) -> None:
    click.echo(f"Warning: {' '.join(str(message).split())}", err=True)


def _error(message: str) -> None:
    click.echo(f"Error: {' '.join(str(message).split())}", err=True)


class _Failed(Exception):
    """A numerical outcome that ends a command with exit status 1 and a one-line reason."""


def _run(func, *args, **kwargs):
    """``func(*args, **kwargs)``; a :class:`_Failed` it raises ends the command with exit 1 (in the group)."""
    return func(*args, **kwargs)


@click.group(cls=PgdGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "-V", "--version", prog_name="pgd", message="%(prog)s %(version)s")
@click.option("--debug", is_flag=True, expose_value=False, is_eager=True,
              callback=lambda ctx, param, value: guard.set_debug(True) if value else None,
              help="Show the traceback of an internal error (also PGD_DEBUG=1).")
def cli():
    """PGD codebooks for parametric dynamical systems.

    Solve a YAML problem spec once, offline, into a codebook (HDF5) holding the
    separated solution u(t, p1, ..., pd) = sum_i alpha_i T_i(t) P_i1(p1)...P_id(pd);
    then query it anywhere in its domain in microseconds.

    \b
      pgd solve problems/parametric.yaml
      pgd query codebooks/parametric.h5 --t 5 --k 2
      pgd info codebooks/parametric.h5

    Exit status: 0 success, 1 solver not converged or a check failed,
    2 invalid input or usage (or a full disk), 70 internal error (a bug;
    --debug shows the traceback). stdout carries data only; progress and
    messages go to stderr.
    """


def _stderr_console():
    from rich.console import Console

    return Console(stderr=True, highlight=False)


# ----------------------------------------------------------------------------------------------
# solve
# ----------------------------------------------------------------------------------------------
@cli.command()
@click.argument("spec", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Codebook path [default: the spec's output, else codebooks/<name>.h5].")
@click.option("--tolerance", type=float,
              help="Override solver.tolerance: the bound on the codebook's max abs error, measured.")
@click.option("--relative-tolerance", type=float, help="Override solver.relative_tolerance (error <= "
              "tolerance + relative_tolerance * |u|).")
@click.option("--max-modes", type=int, help="Override solver.max_modes.")
@click.option("--keep-inaccurate", is_flag=True,
              help="Write the codebook even when its measured error exceeds the tolerance (marked as such in "
                   "the file; the exit status is still 1).")
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True,
              help="text: summary table on stderr; json: the summary as JSON on stdout.")
@click.option("-q", "--quiet", is_flag=True, help="No progress or summary on stderr.")
def solve(spec, output, tolerance, relative_tolerance, max_modes, keep_inaccurate, fmt, quiet):
    """Solve the problem in SPEC (YAML) and write its codebook.

    After the solve, the codebook's error is measured against an independent
    scipy reference. The codebook is written (atomically) only when the solver
    converged and that error meets the tolerance; otherwise nothing is written
    at the target path and the exit status is 1, with one line saying how large
    the error is, where, and what lacks resolution (--keep-inaccurate writes a
    codebook that misses its tolerance anyway, marked in the file).
    """
    _run(_solve, spec, output, tolerance, relative_tolerance, max_modes, keep_inaccurate, fmt, quiet)


def _solve(spec, output, tolerance, relative_tolerance, max_modes, keep_inaccurate, fmt, quiet):
    from .outputs import prepare_output
    from ..driver import solve as solve_problem
    from ..problem.spec import load_spec

    problem = load_spec(spec)
    target = Path(output) if output is not None else Path(problem.output)
    console = None if quiet else _stderr_console()
    tol = problem.solver.tolerance if tolerance is None else tolerance
    nmax = problem.solver.max_modes if max_modes is None else max_modes
    if tolerance is not None and not 0.0 < tolerance < 1.0:
        raise click.BadParameter(f"expected a number in (0, 1), got {tolerance}", param_hint="'--tolerance'")
    if max_modes is not None and max_modes < 1:
        raise click.BadParameter(f"expected an integer >= 1, got {max_modes}", param_hint="'--max-modes'")
    if relative_tolerance is not None and not 0.0 <= relative_tolerance < 1.0:
        raise click.BadParameter(f"expected a number in [0, 1), got {relative_tolerance}",
                                 param_hint="'--relative-tolerance'")
    overrides = {"tolerance": tolerance, "relative_tolerance": relative_tolerance, "max_modes": max_modes}
    prepare_output(target, "--output" if output is not None else f"{spec}: output")  # before the solve
    if console is None:
        result = solve_problem(problem, **overrides)
    else:
        result = _solve_with_progress(console, problem, tol, nmax, solve_problem, overrides)
    for warning in result.warnings:
        _warn(warning)
    keep = result.converged or (keep_inaccurate and result.accurate is False)
    summary = _solve_summary(problem, result, target if keep else None)
    summary["warnings"] = list(result.warnings)
    if keep:
        result.codebook.save(target)
        summary["size_bytes"] = target.stat().st_size
    if console is not None:
        console.print(_summary_table(summary))
    if fmt == "json":
        click.echo(json.dumps(summary, indent=2))
    if not result.converged:
        written = (f"written anyway to {target}, marked inaccurate (--keep-inaccurate)" if keep
                   else f"no codebook written to {target}")
        raise _Failed(f"{spec}: {result.message}; {written}")


def _solve_with_progress(console, problem, tol, nmax, solve_problem, overrides):
    """Enrichment: residual decades reached / decades asked; march: time reached / time domain."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    columns = (TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.fields[status]}"),
               TimeElapsedColumn())
    with Progress(*columns, console=console, transient=False) as progress:
        span = -math.log10(tol)
        task = progress.add_task(f"solving {problem.name}", total=span, status="starting")

        def callback(info):
            if "time" in info:  # separated time march
                t0 = problem.time_coordinate.domain[0]
                frac = (info["time"] - t0) / (info["end"] - t0)
                rank = max((max(r) for r in info["ranks"] if r), default=1)
                progress.update(task, completed=span * frac,
                                status=f"t = {info['time']:.4g}/{info['end']:.4g}  {info['steps']} steps  "
                                       f"max rank {rank}")
                return
            r = info["residual"]
            done = min(span, -math.log10(r) if r > 0 else span)
            progress.update(task, completed=max(done, 0.0),
                            status=f"{info['mode']}/{nmax} modes  residual {r:.2e} (tolerance {tol:.0e})")

        return solve_problem(problem, callback=callback, **overrides)


def _solve_summary(problem, result, target: Path | None) -> dict:
    cb = result.codebook
    rep = cb.report
    march = rep.get("method") == "march"
    # a march that failed holds no solution: its fields are placeholders, not ranks to report
    placeholder = march and result.status == 3
    return {
        "problem": problem.name,
        "method": "march" if march else "pgd",
        "converged": bool(result.converged),
        "accurate": result.accurate,
        "message": result.message,
        "residual": _finite_or_none(result.residual),  # march: the RMS error estimate; null if none
        **({"check_error": _finite_or_none(rep["check_error"]), "check_points": int(rep["check_points"]),
            "check_ratio": _finite_or_none(rep["check_ratio"]), "check_where": _short_where(rep["check_where"]),
            "check_method": str(rep["check_method"])}
           if "check_error" in rep else {}),
        "relative_tolerance": float(rep.get("relative_tolerance", 0.0)),
        "resolution": _resolution_summary(cb),
        **({key: float(rep[key]) for key in ("failed_time", "blowup_time") if key in rep} if placeholder else {}),
        "tolerance": float(rep["tolerance"]),
        # march: the largest tensor-train rank
        "modes": None if placeholder else {u: fm.rank for u, fm in cb.fields.items()},
        "ranks": None if placeholder else {u: list(fm.ranks) for u, fm in cb.fields.items() if hasattr(fm, "ranks")},
        "coordinates": {c.name: c.nodes for c in cb.coordinates},
        "slabs": {c.name: len(c.breakpoints) - 1 for c in cb.coordinates if c.breakpoints},
        "wall_time": float(result.wall_time),
        "output": None if target is None else str(target),
        **({"separated_coefficients": cb.info()["separated_coefficients"]} if "separated_coefficients" in rep else {}),
    }


def _resolution_summary(cb) -> dict | None:
    """``Codebook.nodes_chosen`` when the solver chose some nodes, else None."""
    chosen = cb.nodes_chosen()
    return chosen if chosen and chosen["automatic"] else None


def _nodes_chosen_text(chosen: dict) -> str:
    """``"t: 33 -> 33; p: 9 -> 17"``: the nodes of each automatic coordinate, solve by solve."""
    return "; ".join(f"{c}: " + " -> ".join(str(r["nodes"][c]) for r in chosen["rounds"]) for c in chosen["automatic"])


def _finite_or_none(value) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def _short_where(where: str) -> str:
    """``"t=0.34776852054, a=0"`` with 6 significant digits (the report keeps them all)."""
    try:
        return ", ".join(f"{k}={float(v):.6g}" for k, v in (kv.split("=") for kv in where.split(", ")))
    except ValueError:
        return where


def _summary_table(summary: dict):
    from rich.markup import escape
    from rich.table import Table

    from ..checks.check import points_text

    table = Table(title=f"pgd solve: {summary['problem']}", show_header=False, title_justify="left")
    table.add_column(style="bold")
    table.add_column()
    if summary.get("accurate") is not False:
        table.add_row("status", "[green]converged[/]" if summary["converged"] else "[red]not converged[/]")
    if summary.get("accurate") is False:
        table.add_row("status", "[red]tolerance not met[/]")
    if summary.get("check_error") is not None:
        table.add_row("max error", f"{summary['check_error']:.3e} at {points_text(summary['check_points'])} "
                                   f"vs scipy (tolerance {summary['tolerance']:.1e}), at {summary['check_where']}")
    if summary.get("resolution"):
        table.add_row("nodes chosen", _nodes_chosen_text(summary["resolution"]))
    if summary.get("method") == "march":
        if summary.get("failed_time") is not None:
            reached = f"t = {summary['failed_time']:.6g}"
            if summary.get("blowup_time") is not None:
                reached += f" (blows up at t ~ {summary['blowup_time']:.4g})"
            table.add_row("reached", reached)
        if summary["residual"] is not None:
            table.add_row("error estimate", f"{summary['residual']:.3e} RMS over the grid (march)")
        if summary["ranks"] is not None:
            table.add_row("TT ranks", ", ".join(f"{u}: {tuple(r)}" for u, r in summary["ranks"].items()))
    else:
        residual = "none" if summary["residual"] is None else f"{summary['residual']:.3e}"
        table.add_row("residual", f"{residual} (relative; the solver's stopping signal)")
        table.add_row("modes", ", ".join(f"{u}: {n}" for u, n in summary["modes"].items()))
    for line in summary.get("separated_coefficients", []):
        table.add_row("separated", escape(line))
    slabs = summary.get("slabs", {})
    table.add_row("nodes", ", ".join(f"{c}: {n}" + (f" ({slabs[c]} slabs)" if c in slabs else "")
                                     for c, n in summary["coordinates"].items()))
    table.add_row("time", f"{summary['wall_time']:.2f} s")
    if summary.get("output"):
        size = summary.get("size_bytes")
        table.add_row("codebook", summary["output"] + (f" ({_human_size(size)})" if size else ""))
    return table


def _human_size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n} B"


# ----------------------------------------------------------------------------------------------
# query
# ----------------------------------------------------------------------------------------------
@cli.command(context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(["plain", "csv", "json"]), default="plain", show_default=True,
              help="plain: values separated by spaces, one line per point; csv: header + coordinates and "
                   "values; json: a list of objects.")
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
    from .stream import Writer

    cb = Codebook.load(codebook)
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
        Writer(sys.stdout, fmt, cb, selected).run(chunks)
    finally:
        if handle is not None:
            handle.close()


# ----------------------------------------------------------------------------------------------
# info
# ----------------------------------------------------------------------------------------------
@cli.command()
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True)
def info(codebook, fmt):
    """Describe CODEBOOK: coordinates, domains, nodes, modes, residual, size, solve time."""
    from ..codebook.codebook import Codebook

    cb = Codebook.load(codebook)
    summary = cb.info(codebook)
    if fmt == "json":
        click.echo(json.dumps(summary, indent=2))
        return
    from rich.console import Console
    from rich.table import Table

    from ..checks.check import points_text

    console = Console(highlight=False, soft_wrap=True)
    console.print(f"[bold]{summary['name']}[/]  {summary['description']}".rstrip())
    coords = Table(title="coordinates", title_justify="left")
    for col in ("name", "role", "domain", "nodes", "discretization"):
        coords.add_column(col)
    for c in summary["coordinates"]:
        nodes = str(c["nodes"]) + (f" ({c['elements']} elements)" if c.get("elements") else "")
        coords.add_row(c["name"], c["role"], f"[{c['domain'][0]:g}, {c['domain'][1]:g}]", nodes, c["discretization"])
    console.print(coords)
    console.print("modes: " + ", ".join(
        f"{u} {v['modes']}" if v.get("representation") != "tensor-train" else f"{u} tensor train, ranks {tuple(v['ranks'])}"
        for u, v in summary["unknowns"].items()))
    if summary.get("rates"):
        console.print("rates: " + ", ".join(f"{rate} = der({x})" for rate, x in summary["rates"].items()))
    for line in summary.get("separated_coefficients", []):
        console.print(f"separated coefficient: {line}", markup=False)
    state = "converged" if summary["converged"] else "NOT converged"
    label = "error estimate (RMS)" if summary.get("method") == "march" else "residual"
    if summary.get("accurate") is False:
        console.print("[bold red]INACCURATE[/]: this codebook misses its tolerance (written with --keep-inaccurate)")
    if summary.get("check") is not None and summary["check"]["error"] is not None:
        chk = summary["check"]
        console.print(f"max error: {chk['error']:.3e} at {points_text(chk['points'])} vs scipy, at {_short_where(chk['where'])} "
                      f"(tolerance {summary['tolerance']:.1e})")
        if chk.get("method"):
            console.print(f"measured: {chk['method']}")
    if summary.get("nodes_chosen") and summary["nodes_chosen"]["automatic"]:
        chosen = summary["nodes_chosen"]
        console.print(f"nodes chosen: {_nodes_chosen_text(chosen)} ({chosen['reason']})")
    console.print(f"{label}: {summary['residual']:.3e} ({state})")
    if summary.get("roundings") is not None:
        r = summary["roundings"]
        console.print(f"tensor-train roundings: {r['exact']} exact, {r['sketched']} randomized "
                      f"({r['redone']} redone with a larger sketch)")
    if summary.get("crosses") is not None:
        c = summary["crosses"]
        failed = f", {c['not_converged']} not converged ({c['failure']})" if c["not_converged"] else ""
        console.print(f"functions of the unknowns: {c['count']} approximations on the state (TT-cross or whole "
                      f"grid){failed}, {c['evaluations']} values, ranks <= {c['max_rank']}")
    console.print(f"solve time: {summary['solve_time']:.3f} s")
    console.print(f"size: {_human_size(summary['size_bytes'])} ({summary['size_bytes']} bytes)")
    console.print(f"format: {summary['format']}, written by pgdcli {summary['pgdcli_version']}, {summary['created']}")


# ----------------------------------------------------------------------------------------------
# plot
# ----------------------------------------------------------------------------------------------
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
def plot_command(codebook, kind, output, field, count, at, over, fix, reference, points, dpi, size):
    """Draw CODEBOOK's modes, convergence, solution or error as a PNG or SVG.

    Prints the path of the written image on stdout.

    \b
      pgd plot codebooks/spring.h5                        # modes: the first 6 per coordinate
      pgd plot codebooks/spring.h5 --kind convergence -o conv.svg
      pgd plot codebooks/spring.h5 --kind solution --at k=1.5 --at k=3,c=0.1 --reference
      pgd plot codebooks/spring.h5 --kind solution --over t,k --fix c=0.2
      pgd plot codebooks/spring.h5 --kind error --over k,c --fix t=4
    """
    from ..plot import figures as plotting
    from .outputs import prepare_output

    target = Path(output) if output is not None else plotting.default_output(codebook, kind)
    prepare_output(target, "--output", suffixes=(".png", ".svg"))  # before the plot is computed
    path = plotting.render(codebook, kind, target, field=field, count=count, at=at, over=over, fix=fix,
                           reference=reference, points=points, dpi=dpi, size=size,
                           warn=lambda message: click.echo(f"Warning: {message}", err=True))
    click.echo(str(path))


# ----------------------------------------------------------------------------------------------
# verify
# ----------------------------------------------------------------------------------------------
_VERIFY_METHODS = ("DOP853", "RK45", "Radau", "BDF", "LSODA")  # pgdcli.checks.reference.METHODS (no numpy import here)


@cli.command("verify")
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--samples", type=click.IntRange(min=1), metavar="N",
              help="Random points of the parameter box, checked in addition to all its corners "
                   "[default: 64; for a time-dependent PDE, whose reference costs ~2 s a point, 4, or one "
                   "per element of its finest linear parameter coordinate].")
@click.option("--sampling", type=click.Choice(["sobol", "lhs"]), default="sobol", show_default=True,
              help="Scrambled Sobol or Latin hypercube sampling.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the samples and of the random times.")
@click.option("--points", type=click.Path(dir_okay=False, path_type=Path), metavar="FILE",
              help="CSV file whose header names the non-time coordinates: check these points instead of "
                   "the samples and corners.")
@click.option("--times", "n_times", type=click.IntRange(min=0), default=16, show_default=True, metavar="N",
              help="Random times, checked in addition to every node of the time coordinate.")
@click.option("--method", type=click.Choice(_VERIFY_METHODS, case_sensitive=False), default="DOP853",
              metavar="[" + "|".join(_VERIFY_METHODS) + "]", show_default=True, help="solve_ivp method of the reference (Radau, BDF or LSODA for stiff problems).")
@click.option("--rtol", type=click.FloatRange(0, 1, min_open=True, max_open=True),
              help="Relative tolerance of the reference [default: 1e-12; 1e-10 with space coordinates].")
@click.option("--atol", type=click.FloatRange(0, 1, min_open=True, max_open=True),
              help="Absolute tolerance of the reference [default: 1e-12].")
@click.option("-j", "--jobs", type=click.IntRange(min=1), metavar="N",
              help="Worker processes [default: all cores]; 1 runs in this process.")
@click.option("--max-error", type=click.FloatRange(min=0), metavar="TOL",
              help="Exit 1 when the max absolute error of an unknown exceeds TOL.")
@click.option("--max-rel-error", type=click.FloatRange(min=0), metavar="TOL",
              help="Exit 1 when the max relative error (max abs error / max |reference|) of an unknown exceeds TOL.")
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True,
              help="text: table on stderr; json: the report as JSON on stdout (keys in docs/verify.md).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar or table on stderr.")
def verify_command(codebook, samples, sampling, seed, points, n_times, method, rtol, atol, jobs, max_error,
                   max_rel_error, fmt, quiet):
    """Check CODEBOOK against an independent reference of its own problem.

    The problem stored in the codebook is integrated again with scipy's
    solve_ivp at sample points of the parameter box (scrambled Sobol plus
    every corner), and the codebook is compared with it at every time node
    and at random times. A table of the errors per unknown goes to stderr.

    Exit status: 0 passed; 1 a reference integration failed or an error
    exceeds --max-error / --max-rel-error (the CI gate); 2 invalid input.

    \b
      pgd verify codebooks/spring.h5
      pgd verify codebooks/spring.h5 --max-error 1e-8 --format json > verify.json
      pgd verify codebooks/spring.h5 --points points.csv --times 100 --method Radau
    """
    _run(_verify, codebook, samples, sampling, seed, points, n_times, method, rtol, atol, jobs, max_error,
         max_rel_error, fmt, quiet)


def _verify(codebook, samples, sampling, seed, points, n_times, method, rtol, atol, jobs, max_error, max_rel_error,
            fmt, quiet):
    from ..checks.verify import verify as verify_codebook

    for hint, value in (("'--max-error'", max_error), ("'--max-rel-error'", max_rel_error)):
        if value is not None and not math.isfinite(value):
            raise click.BadParameter(f"expected a finite number >= 0, got {value}", param_hint=hint)
    method = next(m for m in _VERIFY_METHODS if m.lower() == method.lower())
    options = dict(samples=samples, sampling=sampling, seed=seed, points=points, times=n_times, method=method,
                   rtol=rtol, atol=atol, jobs=jobs, max_error=max_error, max_rel_error=max_rel_error)
    console = None if quiet else _stderr_console()
    if console is None:
        report = verify_codebook(codebook, **options)
    else:
        report = _verify_with_progress(console, codebook, verify_codebook, options)
        for renderable in _verify_tables(report, max_error, max_rel_error):
            console.print(renderable)
    if fmt == "json":
        click.echo(json.dumps(report.to_dict(), indent=2))
    reasons = report.violations(max_error, max_rel_error)
    if reasons:
        raise _Failed(f"{codebook}: verification failed: " + "; ".join(reasons))


def _verify_with_progress(console, codebook, verify_codebook, options):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    # no refresh thread (auto_refresh=False): the worker pool may then fork this process safely
    progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                        TextColumn("parameter points"), TimeElapsedColumn(), console=console, auto_refresh=False)
    state = {}

    def callback(done, total):
        if "task" not in state:
            progress.start()
            state["task"] = progress.add_task(f"verifying {Path(codebook).name}", total=total)
        progress.update(state["task"], completed=done)
        progress.refresh()

    try:
        return verify_codebook(codebook, progress=callback, **options)
    finally:
        if "task" in state:
            progress.stop()


def _verify_tables(report, max_error, max_rel_error) -> list:
    from rich.table import Table

    def number(value):
        return "n/a" if not math.isfinite(value) else f"{value:.3e}"

    s = report.settings
    if s["sampling"] == "points":
        where = f"{s['parameter_points']} parameter points from {s['points_file'] or 'the given points'}"
    else:
        capped = f" (capped at {s['corners']})" if s["corners"] < s["corners_total"] else ""
        where = (f"{s['parameter_points']} parameter points ({s['samples']} {s['sampling']} + "
                 f"{s['corners_total']} corners{capped})")
    if report.time is None:
        caption = f"{where}, steady; reference: Chebyshev collocation, sparse direct solve, {s['jobs']} job(s), "
    else:
        caption = (f"{where} x {s['times']} times ({s['time_nodes']} nodes + {s['random_times']} random); "
                   f"reference {s['method']} rtol {s['rtol']:.0e} atol {s['atol']:.0e}, {s['jobs']} job(s), ")
    caption += f"{report.wall_time:.2f} s. rel error = max abs error / max |reference| of the unknown."
    table = Table(title=f"pgd verify: {report.problem}", title_justify="left", caption=caption,
                  caption_justify="left")
    for column in ("unknown", "max abs error", "max rel error", "RMS error", "max |reference|", "worst at"):
        table.add_column(column, justify="left" if column in ("unknown", "worst at") else "right")
    for name, stats in report.unknowns.items():
        at = ", ".join(f"{k}={v:.6g}" for k, v in stats.where.items()) if math.isfinite(stats.max_abs_error) else "n/a"
        table.add_row(name, number(stats.max_abs_error), number(stats.max_rel_error), number(stats.rms_error),
                      number(stats.reference_scale), at)
    out: list = [table]
    if report.failures:
        failed = Table(title=f"reference failed at {len(report.failures)} of {s['parameter_points']} parameter points",
                       title_justify="left", title_style="bold red")
        failed.add_column("point")
        failed.add_column("reason")
        for failure in report.failures[:10]:
            failed.add_row(", ".join(f"{k}={v:.6g}" for k, v in failure.point.items()) or "-", failure.message)
        if len(report.failures) > 10:
            failed.add_row(f"... {len(report.failures) - 10} more", "(all in --format json)")
        out.append(failed)
    gates = ["every reference integration succeeds"]
    if max_error is not None:
        gates.append(f"max abs error <= {max_error:.3g}")
    if max_rel_error is not None:
        gates.append(f"max rel error <= {max_rel_error:.3g}")
    verdict = "[green]passed[/]" if report.passed(max_error, max_rel_error) else "[red]FAILED[/]"
    out.append(f"{verdict} (gate: {', '.join(gates)})")
    return out


# ----------------------------------------------------------------------------------------------
# fit (pgdcli.inference.fitting) and export (pgdcli.codebook.export)
# ----------------------------------------------------------------------------------------------
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
@click.option("--format", "fmt", type=click.Choice(["plain", "csv", "json"]), default="plain", show_default=True,
              help="plain: 'name estimate stderr' per free coordinate; csv: the fitted curve; json: everything.")
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

    \b
      pgd fit codebooks/coupled.h5 trajectory.csv --sigma u1=1e-3 --format json
    """
    from ..inference.fitting import fit
    from ..inference.report import plot_fit, summary, write_result

    label = "DATA (stdin)" if data.name == "<stdin>" else str(data.name)
    result = fit(codebook, data, fix=_assignments(fix, "--fix"), sigma=_assignments(sigma, "--sigma"),
                 starts=starts, seed=seed, check=not no_check, label=label)
    write_result(sys.stdout, result, fmt)
    if plot_path is not None:
        plot_fit(result, plot_path)
    if not quiet:
        click.echo(summary(result), err=True)


@cli.command("export")
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--to", "target", type=click.Choice(["c", "glsl", "json"]), required=True,
              help="c: one C99 header (double and float32 evaluators); glsl: a shader function; json: the numbers.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), metavar="FILE",
              help="Write to FILE [default: stdout].")
@click.option("--force", is_flag=True, help="Export even past the size limit (16 MiB of float64 numbers).")
@click.option("-q", "--quiet", is_flag=True, help="No size line on stderr.")
def export_command(codebook, target, output, force, quiet):
    """Write a self-contained evaluator of CODEBOOK for engines and other languages.

    \b
      pgd export codebooks/rigid_body.h5 --to c -o pgd_rigid_body.h
      pgd export codebooks/coupled.h5 --to json > coupled.json
    """
    from ..codebook.codebook import Codebook
    from ..codebook.export import export

    cb = Codebook.load(codebook)
    files, size = export(cb, target, force=force)
    ((name, text),) = files.items()
    if output is None:
        sys.stdout.write(text)
    else:
        try:
            output.write_text(text)
        except OSError as exc:
            raise click.BadParameter(f"cannot write {output} ({exc.strerror or exc})", param_hint="'-o'") from None
    if not quiet:
        where = output if output is not None else f"stdout ({name})"
        click.echo(f"exported {cb.name} to {target}: {size // 8} numbers, {size / 2**20:.2f} MiB as float64; "
                   f"{len(text.encode()) / 2**20:.2f} MiB of text to {where}", err=True)


def main(argv=None) -> None:
    """Console-script entry point.

    A plain ``pgd query`` runs in :mod:`pgdcli.cli.query` (no click machinery); everything
    else, and any query that fails or asks for help, runs through click as usual.
    """
    from .query import main as query_first

    query_first(argv)


if __name__ == "__main__":  # pragma: no cover
    main()
