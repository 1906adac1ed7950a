"""The ``pgd`` command line: a thin layer over the library.

Each command parses its options, calls one library function and formats the
result. stdout carries data only; progress, tables and messages go to stderr.
Exit status: 0 success, 1 a numerical outcome the user asked to be told
about (solver not converged, verification gate failed), 2 invalid input
(one ``Error:`` line, no traceback).

This is the only module that imports click and rich; rich is imported only by
the commands that draw with it, so ``pgd query`` stays lean.
"""

from __future__ import annotations

import io
import json
import math
import sys
from pathlib import Path

import click

from . import __version__
from .errors import PgdError, QueryError

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


# ----------------------------------------------------------------------------------------------
# one-line errors for every usage problem
# ----------------------------------------------------------------------------------------------
class PgdGroup(click.Group):
    """A click group whose errors are one ``Error:`` line on stderr (exit 2), never a traceback."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        try:
            code = super().main(args=args, prog_name=prog_name or "pgd", complete_var=complete_var,
                                standalone_mode=False, **extra)
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
            code = 130
        except BrokenPipeError:
            # a pipeline reader went away (e.g. `pgd query ... | head`): not an error
            sys.stderr.close()
            code = EXIT_OK
        if not isinstance(code, int):
            code = EXIT_OK
        if standalone_mode:
            sys.exit(code)
        return code


def _error(message: str) -> None:
    click.echo(f"Error: {' '.join(str(message).split())}", err=True)


class _Failed(Exception):
    """A numerical outcome that ends a command with exit status 1 and a one-line reason."""


def _run(func, *args, **kwargs):
    try:
        return func(*args, **kwargs)
    except _Failed as exc:
        _error(str(exc))
        sys.exit(EXIT_FAILED)


@click.group(cls=PgdGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "-V", "--version", prog_name="pgd", message="%(prog)s %(version)s")
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
    2 invalid input or usage. stdout carries data only; progress and
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
@click.option("--tolerance", type=float, help="Override solver.tolerance (relative residual).")
@click.option("--max-modes", type=int, help="Override solver.max_modes.")
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True,
              help="text: summary table on stderr; json: the summary as JSON on stdout.")
@click.option("-q", "--quiet", is_flag=True, help="No progress or summary on stderr.")
def solve(spec, output, tolerance, max_modes, fmt, quiet):
    """Solve the problem in SPEC (YAML) and write its codebook.

    The codebook is written (atomically) only when the relative residual
    reaches the tolerance; otherwise nothing is written at the target path
    and the exit status is 1.
    """
    _run(_solve, spec, output, tolerance, max_modes, fmt, quiet)


def _solve(spec, output, tolerance, max_modes, fmt, quiet):
    from .solver import solve as solve_problem
    from .spec import load_spec

    problem = load_spec(spec)
    target = Path(output) if output is not None else Path(problem.output)
    console = None if quiet else _stderr_console()
    tol = problem.solver.tolerance if tolerance is None else tolerance
    nmax = problem.solver.max_modes if max_modes is None else max_modes
    if tolerance is not None and not 0.0 < tolerance < 1.0:
        raise click.BadParameter(f"expected a number in (0, 1), got {tolerance}", param_hint="'--tolerance'")
    if max_modes is not None and max_modes < 1:
        raise click.BadParameter(f"expected an integer >= 1, got {max_modes}", param_hint="'--max-modes'")
    if console is None:
        result = solve_problem(problem, tolerance=tolerance, max_modes=max_modes)
    else:
        result = _solve_with_progress(console, problem, tol, nmax, solve_problem, tolerance, max_modes)
    summary = _solve_summary(problem, result, target)
    if result.converged:
        result.codebook.save(target)
        summary["size_bytes"] = target.stat().st_size
    if console is not None:
        console.print(_summary_table(summary))
    if fmt == "json":
        click.echo(json.dumps(summary, indent=2))
    if not result.converged:
        raise _Failed(f"{spec}: {result.message}; no codebook written to {target}")


def _solve_with_progress(console, problem, tol, nmax, solve_problem, tolerance, max_modes):
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    columns = (TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.fields[status]}"),
               TimeElapsedColumn())
    with Progress(*columns, console=console, transient=False) as progress:
        start = -math.log10(1.0)
        span = -math.log10(tol) - start
        task = progress.add_task(f"solving {problem.name}", total=span, status=f"0 modes")

        def callback(info):
            r = info["residual"]
            done = min(span, -math.log10(r) if r > 0 else span)
            progress.update(task, completed=max(done, 0.0),
                            status=f"{info['mode']}/{nmax} modes  residual {r:.2e} (tolerance {tol:.0e})")

        return solve_problem(problem, tolerance=tolerance, max_modes=max_modes, callback=callback)


def _solve_summary(problem, result, target: Path) -> dict:
    return {
        "problem": problem.name,
        "converged": bool(result.converged),
        "message": result.message,
        "residual": float(result.residual),
        "tolerance": float(result.codebook.report["tolerance"]),
        "modes": {u: fm.rank for u, fm in result.codebook.fields.items()},
        "coordinates": {c.name: c.nodes for c in problem.coordinates},
        "wall_time": float(result.wall_time),
        "output": str(target) if result.converged else None,
    }


def _summary_table(summary: dict):
    from rich.table import Table

    table = Table(title=f"pgd solve: {summary['problem']}", show_header=False, title_justify="left")
    table.add_column(style="bold")
    table.add_column()
    status = "[green]converged[/]" if summary["converged"] else "[red]not converged[/]"
    table.add_row("status", status)
    table.add_row("residual", f"{summary['residual']:.3e} (tolerance {summary['tolerance']:.1e})")
    table.add_row("modes", ", ".join(f"{u}: {n}" for u, n in summary["modes"].items()))
    table.add_row("nodes", ", ".join(f"{c}: {n}" for c, n in summary["coordinates"].items()))
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
@click.option("--points", type=click.File("r"), metavar="FILE",
              help="CSV file whose header names the coordinates ('-' for stdin): one output row per input row.")
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
    from .codebook import Codebook

    cb = Codebook.load(codebook)
    selected = list(fields) if fields else cb.unknown_names
    for f in selected:
        if f not in cb.fields:
            raise click.BadParameter(f"unknown field {f!r}; this codebook has {', '.join(cb.unknown_names)}",
                                     param_hint="'--field'")
    if points is not None:
        if ctx.args:
            raise click.UsageError("give either --points FILE or --NAME VALUE options, not both")
        coords = _read_points(points, cb)
    else:
        coords = _grid_from_args(ctx.args, cb)
    values = cb.evaluate(coords, fields=selected)
    _write_rows(sys.stdout, fmt, cb.coordinate_names, coords, selected, values)


def _parse_coordinate_args(args: list[str], cb) -> dict[str, str]:
    given: dict[str, str] = {}
    i = 0
    names = cb.coordinate_names
    while i < len(args):
        arg = args[i]
        if not arg.startswith("--") or len(arg) == 2:
            raise click.UsageError(f"unexpected argument {arg!r}; coordinates are given as --NAME VALUE "
                                   f"({' '.join('--' + n for n in names)})")
        name, eq, value = arg[2:].partition("=")
        if not eq:
            if i + 1 >= len(args):
                raise click.UsageError(f"option '--{name}' needs a value")
            value = args[i + 1]
            i += 1
        i += 1
        if name not in names:
            raise QueryError(f"unknown coordinate '--{name}'; this codebook has "
                             f"{', '.join(_describe(c) for c in cb.coordinates)}")
        if name in given:
            raise click.UsageError(f"coordinate '--{name}' given twice")
        given[name] = value
    missing = [c for c in cb.coordinates if c.name not in given]
    if missing:
        raise QueryError("missing coordinate " + ", ".join(f"'--{c.name}' ({_describe(c)})" for c in missing))
    return given


def _describe(c) -> str:
    return f"{c.name} in [{c.domain[0]:g}, {c.domain[1]:g}]"


def _parse_values(name: str, text: str):
    import numpy as np

    text = text.strip()
    try:
        if ":" in text:
            parts = text.split(":")
            if len(parts) != 3:
                raise ValueError
            start, stop, count = float(parts[0]), float(parts[1]), int(parts[2])
            if count < 1:
                raise ValueError
            return np.linspace(start, stop, count)
        return np.array([float(v) for v in text.split(",")], dtype=float)
    except ValueError:
        raise click.BadParameter(
            f"{text!r} is not a number, a comma list or start:stop:count", param_hint=f"'--{name}'"
        ) from None


def _grid_from_args(args: list[str], cb) -> dict:
    import numpy as np

    given = _parse_coordinate_args(args, cb)
    lists = [_parse_values(c.name, given[c.name]) for c in cb.coordinates]
    for c, v in zip(cb.coordinates, lists):
        _check_domain(c, v)
    grids = np.meshgrid(*lists, indexing="ij")
    return {c.name: g.reshape(-1) for c, g in zip(cb.coordinates, grids)}


def _check_domain(c, values) -> None:
    import numpy as np

    bad = ~np.isfinite(values) | (values < c.domain[0]) | (values > c.domain[1])
    if bad.any():
        raise QueryError(f"coordinate '--{c.name}': value {float(values[bad][0])!r} is outside the domain "
                         f"[{c.domain[0]:g}, {c.domain[1]:g}]")


def _read_points(handle, cb) -> dict:
    import csv

    import numpy as np

    source = getattr(handle, "name", "points")
    source = "stdin" if source == "<stdin>" else source
    reader = csv.reader(handle)
    header = next(reader, None)
    if header is None:
        raise QueryError(f"{source}: empty points file; expected a CSV header naming the coordinates")
    header = [h.strip() for h in header]
    names = cb.coordinate_names
    for h in header:
        if h not in names:
            raise QueryError(f"{source}: unknown column {h!r}; expected the coordinates {', '.join(names)}")
    missing = [n for n in names if n not in header]
    if missing:
        raise QueryError(f"{source}: missing column(s) {', '.join(missing)}")
    rows = []
    for line, row in enumerate(reader, start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise QueryError(f"{source}: line {line}: expected {len(header)} values, got {len(row)}")
        try:
            rows.append([float(cell) for cell in row])
        except ValueError:
            raise QueryError(f"{source}: line {line}: not a number in {','.join(row)!r}") from None
    data = np.array(rows, dtype=float).reshape(-1, len(header))
    coords = {h: data[:, i] for i, h in enumerate(header)}
    for c in cb.coordinates:
        _check_domain(c, coords[c.name])
    return {n: coords[n] for n in names}


def _write_rows(out, fmt, coord_names, coords, selected, values) -> None:
    import numpy as np

    n = len(next(iter(coords.values()))) if coords else 0
    cols = [np.asarray(values[f]).reshape(-1).tolist() for f in selected]
    buf = io.StringIO()
    if fmt == "plain":
        for row in zip(*cols):
            buf.write(" ".join(map(repr, row)))
            buf.write("\n")
    elif fmt == "csv":
        ccols = [np.asarray(coords[c]).reshape(-1).tolist() for c in coord_names]
        buf.write(",".join(coord_names + selected) + "\n")
        for row in zip(*ccols, *cols):
            buf.write(",".join(map(repr, row)))
            buf.write("\n")
    else:
        ccols = [np.asarray(coords[c]).reshape(-1).tolist() for c in coord_names]
        keys = coord_names + selected
        records = [dict(zip(keys, row)) for row in zip(*ccols, *cols)]
        buf.write(json.dumps(records))
        buf.write("\n")
    assert n == len(cols[0]) if cols else True
    out.write(buf.getvalue())
    out.flush()


# ----------------------------------------------------------------------------------------------
# info
# ----------------------------------------------------------------------------------------------
@cli.command()
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True)
def info(codebook, fmt):
    """Describe CODEBOOK: coordinates, domains, nodes, modes, residual, size, solve time."""
    from .codebook import Codebook

    cb = Codebook.load(codebook)
    summary = cb.info(codebook)
    if fmt == "json":
        click.echo(json.dumps(summary, indent=2))
        return
    from rich.console import Console
    from rich.table import Table

    console = Console(highlight=False, soft_wrap=True)
    console.print(f"[bold]{summary['name']}[/]  {summary['description']}".rstrip())
    coords = Table(title="coordinates", title_justify="left")
    for col in ("name", "role", "domain", "nodes", "discretization"):
        coords.add_column(col)
    for c in summary["coordinates"]:
        coords.add_row(c["name"], c["role"], f"[{c['domain'][0]:g}, {c['domain'][1]:g}]", str(c["nodes"]),
                       c["discretization"])
    console.print(coords)
    console.print("modes: " + ", ".join(f"{u} {v['modes']}" for u, v in summary["unknowns"].items()))
    state = "converged" if summary["converged"] else "NOT converged"
    console.print(f"residual: {summary['residual']:.3e} (tolerance {summary['tolerance']:.1e}, {state})")
    console.print(f"solve time: {summary['solve_time']:.3f} s")
    console.print(f"size: {_human_size(summary['size_bytes'])} ({summary['size_bytes']} bytes)")
    console.print(f"format: {summary['format']}, written by pgdcli {summary['pgdcli_version']}, {summary['created']}")


def main(argv=None) -> None:
    """Console-script entry point."""
    cli.main(args=argv, prog_name="pgd")


if __name__ == "__main__":  # pragma: no cover
    main()
