"""``pgd solve``: spec -> checked codebook, with progress and a summary table."""

from __future__ import annotations

import contextlib
import json
import math
from functools import partial
from pathlib import Path

import click

from .cluster_options import cluster_options, open_executor
from .formats import SOLVE
from .group import Failed, cli, format_option, run_command, stderr_console, warn
from .outputs import prepare_output
from .progress_view import solve_progress
from .solve_family import family_specs, solve_family
from .text import human_size, nodes_chosen_text, short_where


@SOLVE.register("text", "summary table on stderr")
def write_nothing(summary: dict | list) -> None:
    """Nothing on stdout: the table is printed on stderr (none with --quiet)."""


@SOLVE.register("json", "the summary as JSON on stdout (several specs: a list, one row per spec)")
def write_json(summary: dict | list) -> None:
    """The summary of one spec, or the rows of several (:func:`~pgdcli.cli.solve_family.solve_family`)."""
    click.echo(json.dumps(summary, indent=2))


@cli.command()
@click.argument("specs", metavar="SPEC...", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path),
              help="Codebook path [default: the spec's output, else codebooks/<name>.h5]; with several specs, "
                   "the folder of their codebooks.")
@click.option("--tolerance", type=float,
              help="Override solver.tolerance: the bound on the codebook's max abs error, measured.")
@click.option("--relative-tolerance", type=float, help="Override solver.relative_tolerance (error <= "
              "tolerance + relative_tolerance * |u|).")
@click.option("--max-modes", type=int, help="Override solver.max_modes.")
@click.option("--keep-inaccurate", is_flag=True,
              help="Write the codebook even when its measured error exceeds the tolerance (marked as such in "
                   "the file; the exit status is still 1).")
@format_option(SOLVE)
@click.option("-q", "--quiet", is_flag=True, help="No progress or summary on stderr.")
@cluster_options("the cross march's batches of trajectories and the reference's chunks (several specs: one task "
                 "each)")
@click.pass_context
def solve(ctx, specs, output, tolerance, relative_tolerance, max_modes, keep_inaccurate, fmt, quiet, scheduler,
          workers):
    """Solve the problem in SPEC (YAML) and write its codebook.

    After the solve, the codebook's error is measured against an independent
    scipy reference. The codebook is written (atomically) only when the solver
    converged and that error meets the tolerance; otherwise nothing is written
    at the target path and the exit status is 1, with one line saying how large
    the error is, where, and what lacks resolution (--keep-inaccurate writes a
    codebook that misses its tolerance anyway, marked in the file).

    Several specs (or a folder of them) are a family: each is built on its own
    (one task each on a cluster), a failure does not stop the others, and a
    table sums them up.
    """
    options = (tolerance, relative_tolerance, max_modes, keep_inaccurate, fmt, quiet)
    family = family_specs(specs)
    cluster = partial(open_executor, ctx, scheduler, workers, quiet)  # opened once the specs are checked
    run_command(_solve if family is None else solve_family, specs[0] if family is None else family, output,
                *options, cluster=cluster)


def _solve(spec, output, tolerance, relative_tolerance, max_modes, keep_inaccurate, fmt, quiet,
           cluster=contextlib.nullcontext):
    from ..driver import check_solvable
    from ..driver import solve as solve_problem
    from ..problem.spec import load_spec

    problem = load_spec(spec)
    target = Path(output) if output is not None else Path(problem.output)
    console = None if quiet else stderr_console()
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
    rtol = problem.solver.relative_tolerance if relative_tolerance is None else relative_tolerance
    check_solvable(problem, tol, rtol, nmax)  # a refusal before the progress bar: one line on stderr
    prepare_output(target, "--output" if output is not None else f"{spec}: output")  # before the solve
    with cluster() as executor:
        overrides["executor"] = executor
        if console is None:
            result = solve_problem(problem, **overrides)
        else:
            result = _solve_with_progress(console, problem, solve_problem, overrides)
    for warning in result.warnings:
        warn(warning)
    keep = result.converged or (keep_inaccurate and result.accurate is False)
    summary = _solve_summary(problem, result, target if keep else None)
    summary["warnings"] = list(result.warnings)
    if keep:
        result.codebook.save(target)
        summary["size_bytes"] = target.stat().st_size
    if console is not None:
        console.print(_summary_table(summary))
    SOLVE.writer(fmt)(summary)
    if not result.converged:
        written = (f"written anyway to {target}, marked inaccurate (--keep-inaccurate)" if keep
                   else f"no codebook written to {target}")
        raise Failed(f"{spec}: {result.message}; {written}")


def _solve_with_progress(console, problem, solve_problem, overrides):
    """The solve with its progress on stderr (:mod:`pgdcli.cli.progress_view`)."""
    with solve_progress(console, problem.name) as view:
        executor = overrides.get("executor")
        if executor is not None:  # the tasks the cluster finished
            view.count_tasks(executor)
        return solve_problem(problem, callback=view, **overrides)


def _solve_summary(problem, result, target: Path | None) -> dict:
    from ..algorithms.outcome import Status
    from ..codebook.summary import coordinate_ratios, event_summary, phase_summary
    from ..tensors.tt import TT
    cb = result.codebook
    rep = cb.report
    march = rep.get("method") == "march"
    pde_march = str(rep.get("method", "")).startswith("pde march")  # its step control has no residual
    # a march that failed holds no solution: its fields are placeholders, not ranks to report
    placeholder = (march or pde_march) and result.status == Status.FAILED
    return {
        "problem": problem.name,
        "method": "march" if march else "pde march" if pde_march else "amen" if rep.get("method") == "amen" else "pgd",
        # a linear problem: which solver ran and why (solver.method, or auto's fallback)
        **({"method_reason": str(rep["method_reason"])} if "method_reason" in rep else {}),
        "converged": bool(result.converged),
        "accurate": result.accurate,
        "message": result.message,
        # march: the RMS error estimate; null if none
        "residual": None if pde_march else _finite_or_none(result.residual),
        **({"steps": int(rep["steps"]), "rejected_steps": int(rep["rejected_steps"])}
           if pde_march and "steps" in rep else {}),
        # the ODE march's state: 'grid' (the whole array, compressed once) or 'train'
        **({"march": str(rep["march"])} if march and "march" in rep else {}),
        **({"check_error": _finite_or_none(rep["check_error"]), "check_points": int(rep["check_points"]),
            "check_ratio": _finite_or_none(rep["check_ratio"]), "check_where": short_where(rep["check_where"]),
            "check_method": str(rep["check_method"]), "check_node_error": _finite_or_none(rep["check_node_error"]),
            "check_between_error": _finite_or_none(rep["check_between_error"]),
            "check_coordinate_ratio": coordinate_ratios(rep)}
           if "check_error" in rep else {}),
        "relative_tolerance": float(rep.get("relative_tolerance", 0.0)),
        "resolution": _resolution_summary(cb),
        **({key: float(rep[key]) for key in ("failed_time", "blowup_time") if key in rep} if placeholder else {}),
        "tolerance": float(rep["tolerance"]),
        # march: the largest tensor-train rank
        "modes": None if placeholder else {u: fm.rank for u, fm in cb.fields.items()},
        "ranks": None if placeholder else {u: list(fm.ranks) for u, fm in cb.fields.items() if isinstance(fm, TT)},
        "coordinates": {c.name: c.nodes for c in cb.coordinates},
        "slabs": {c.name: len(c.breakpoints) - 1 for c in cb.coordinates if c.breakpoints},
        "wall_time": float(result.wall_time),
        "gate_time": float(rep["gate_time"]) if "gate_time" in rep else None,
        "output": None if target is None else str(target),
        **({"separated_coefficients": cb.info()["separated_coefficients"]} if "separated_coefficients" in rep else {}),
        **({"events": event_summary(cb)} if cb.events else {}),
        **({"phases": phase_summary(cb)} if getattr(cb, "phases", None) is not None else {}),
    }


def _resolution_summary(cb) -> dict | None:
    """``Codebook.nodes_chosen`` when the solver chose some nodes, else None."""
    chosen = cb.nodes_chosen()
    return chosen if chosen and chosen["automatic"] else None


def _finite_or_none(value) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def _time_text(summary: dict) -> str:
    """The build's wall time and the error gate's share of it."""
    wall, check = summary["wall_time"], summary.get("gate_time")
    if check is None or not wall > 0:
        return f"{wall:.2f} s"
    return f"{wall:.2f} s, of which the error gate {check:.2f} s ({100 * check / wall:.0f}%)"


def _error_text(summary: dict) -> str:
    """The measured error; with phases, the whole motion's first (the first phase's is its start only)."""
    from ..checks.check import points_text

    error = (f"{summary['check_error']:.3e} at {points_text(summary['check_points'])} vs scipy (tolerance "
             f"{summary['tolerance']:.1e}), at {summary['check_where']}")
    phases = summary.get("phases") or {}
    if phases.get("error") is None or phases["action"] == "terminal":
        return error
    return (f"{phases['error']:.3e} over the {phases['count']} phases vs solve_ivp restarted at each event "
            f"(tolerance {summary['tolerance']:.1e}); the first phase: {error}")


def _summary_table(summary: dict):
    from rich.markup import escape
    from rich.table import Table

    from ..codebook.summary import phase_text

    table = Table(title=f"pgd solve: {summary['problem']}", show_header=False, title_justify="left")
    table.add_column(style="bold")
    table.add_column()
    if summary.get("accurate") is not False:
        table.add_row("status", "[green]converged[/]" if summary["converged"] else "[red]not converged[/]")
    if summary.get("accurate") is False:
        table.add_row("status", "[red]tolerance not met[/]")
    if summary.get("check_error") is not None:
        table.add_row("max error", _error_text(summary))
    if summary.get("resolution"):
        table.add_row("nodes chosen", nodes_chosen_text(summary["resolution"]))
    if summary.get("method") == "march":
        if summary.get("failed_time") is not None:
            reached = f"t = {summary['failed_time']:.6g}"
            if summary.get("blowup_time") is not None:
                reached += f" (blows up at t ~ {summary['blowup_time']:.4g})"
            table.add_row("reached", reached)
        if summary["residual"] is not None:
            how = {"grid": ", the grid's whole array", "train": ", a tensor train"}.get(summary.get("march"), "")
            table.add_row("error estimate", f"{summary['residual']:.3e} RMS over the grid (march{how})")
        if summary["ranks"] is not None:
            table.add_row("TT ranks", ", ".join(f"{u}: {tuple(r)}" for u, r in summary["ranks"].items()))
    elif summary.get("method") == "pde march":
        if "steps" in summary:
            table.add_row("steps", f"{summary['steps']} ({summary['rejected_steps']} rejected), ETDRK4")
        if summary["ranks"]:
            table.add_row("TT ranks", ", ".join(f"{u}: {tuple(r)}" for u, r in summary["ranks"].items()))
    else:
        residual = "none" if summary["residual"] is None else f"{summary['residual']:.3e}"
        if summary.get("method_reason"):
            name = "tensor-train solver (amen)" if summary["method"] == "amen" else "enrichment (pgd)"
            table.add_row("method", f"{name}: {escape(summary['method_reason'])}")
        if summary["method"] == "amen":
            table.add_row("residual", f"{residual} (2-norm at the nodes; the solver's stopping signal)")
            table.add_row("TT ranks", ", ".join(f"{u}: {tuple(r)}" for u, r in summary["ranks"].items()))
        else:
            table.add_row("residual", f"{residual} (relative; the solver's stopping signal)")
            table.add_row("modes", ", ".join(f"{u}: {n}" for u, n in summary["modes"].items()))
    for line in summary.get("separated_coefficients", []):
        table.add_row("separated", escape(line))
    slabs = summary.get("slabs", {})
    table.add_row("nodes", ", ".join(f"{c}: {n}" + (f" ({slabs[c]} slabs)" if c in slabs else "")
                                     for c, n in summary["coordinates"].items()))
    for name, event in summary.get("events", {}).items():
        error = "" if event["error"] is None else f": time within {event['error']:.2e} of scipy's event location"
        table.add_row(f"event {escape(name)}", escape(f"{event['when']} ({event['direction']})") + error)
    if "phases" in summary:
        table.add_row("phases", escape(f"event {summary['phases']['event']} {phase_text(summary['phases'])}"))
    table.add_row("time", _time_text(summary))
    if summary.get("output"):
        size = summary.get("size_bytes")
        table.add_row("codebook", summary["output"] + (f" ({human_size(size)})" if size else ""))
    return table
