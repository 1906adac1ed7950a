"""``pgd info``: what a codebook holds and how it was made."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..errors import CodebookError
from ..names import printable
from .formats import INFO
from .group import cli, format_option
from .text import human_size, nodes_chosen_text, short_where


@INFO.register("text", "a readable summary")
def write_text(summary: dict) -> None:
    """The summary as rich text: what the codebook holds, then how it was made."""
    from rich.console import Console

    summary = _shown(summary)
    console = Console(highlight=False, soft_wrap=True)
    _print_contents(console, summary)
    _print_solve(console, summary)


@INFO.register("json", "every figure as JSON")
def write_json(summary: dict) -> None:
    click.echo(json.dumps(summary, indent=2))  # JSON escapes control characters itself


def _print_contents(console, summary: dict) -> None:
    """Name, coordinates, modes, rate unknowns and separated coefficients."""
    from rich.table import Table

    from ..codebook.summary import phase_text

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
        console.print(f"separated coefficient: {line}")
    for name, event in summary.get("events", {}).items():  # pgd query --event NAME
        error = "" if event["error"] is None else f", time within {event['error']:.2e} of scipy's event location"
        console.print(f"event {name}: {event['when']} ({event['direction']}){error}")
    phases = summary.get("phases")
    if phases is not None:
        console.print(f"event {phases['event']} {phase_text(phases)}")
    if summary.get("method_reason"):  # escaped for rich by _shown, as every string of the summary
        name = "tensor-train solver (amen)" if summary["method"] == "amen" else "enrichment (pgd)"
        console.print(f"method: {name}: {summary['method_reason']}")


def _print_solve(console, summary: dict) -> None:
    """The solve: its check, the nodes chosen, steps or residual, the march, time, size and format."""
    from ..checks.check import points_text

    state = "converged" if summary["converged"] else "NOT converged"
    label = "error estimate (RMS)" if summary.get("method") == "march" else "residual"
    if summary.get("accurate") is False:
        console.print("[bold red]INACCURATE[/]: this codebook misses its tolerance (written with --keep-inaccurate)")
    if summary.get("check") is not None and summary["check"]["error"] is not None:
        chk = summary["check"]
        console.print(f"max error: {chk['error']:.3e} at {points_text(chk['points'])} vs scipy, at {short_where(chk['where'])} "
                      f"(tolerance {summary['tolerance']:.1e})")
        if chk.get("method"):
            console.print(f"measured: {chk['method']}")
    if summary.get("nodes_chosen") and summary["nodes_chosen"]["automatic"]:
        chosen = summary["nodes_chosen"]
        console.print(f"nodes chosen: {nodes_chosen_text(chosen)} ({chosen['reason']})")
    if summary.get("method", "").startswith("pde march"):  # its step control has no residual
        console.print(f"steps: {summary.get('steps')} ({summary.get('rejected_steps')} rejected), ETDRK4 ({state})")
    else:
        console.print(f"{label}: {summary['residual']:.3e} ({state})")
    if summary.get("march") == "grid":
        console.print("march: the whole grid array (grid march), compressed once by TT-SVD")
    if summary.get("cross_abandoned"):
        console.print(f"the cross march, tried first, gave up: {summary['cross_abandoned']}")
    if summary.get("cross_march") is not None:
        c = summary["cross_march"]
        console.print(f"march: the cross of trajectories (cross march): {c['trajectories']:,} trajectories in "
                      f"{c['sweeps']} half sweeps, steps from a pilot of {c['pilot_points']:,} nodes; "
                      f"root-mean-square difference {c['error']:.2e} at random nodes")
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
    console.print(f"size: {human_size(summary['size_bytes'])} ({summary['size_bytes']} bytes)")
    console.print(f"format: {summary['format']}, written by pgdcli {summary['pgdcli_version']}, {summary['created']}")
    console.print(f"integrity: {summary['integrity']}")


def _shown(value):
    """Every string of a summary safe for a terminal: control characters escaped, rich markup inert."""
    from rich.markup import escape


    if isinstance(value, str):
        return escape(printable(value, 2000))
    if isinstance(value, dict):
        return {_shown(k): _shown(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_shown(v) for v in value]
    return value


@cli.command()
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@format_option(INFO)
@click.option("--spec", "show_spec", is_flag=True,
              help="Print the problem spec stored in CODEBOOK (YAML, as it was solved) instead.")
def info(codebook, fmt, show_spec):
    """Describe CODEBOOK: coordinates, domains, nodes, modes, residual, size, solve time.

    \b
      pgd info codebooks/coupled.h5
      pgd info codebooks/coupled.h5 --format json
      pgd info codebooks/coupled.h5 --spec > coupled.yaml    # solve it again: pgd solve coupled.yaml
    """
    from ..codebook.codebook import Codebook

    cb = Codebook.load(codebook)
    if show_spec:
        if not cb.spec_text.strip():
            raise CodebookError(f"{codebook}: the codebook holds no problem spec")
        click.echo(cb.spec_text, nl=not cb.spec_text.endswith("\n"))
        return
    INFO.writer(fmt)(cb.info(codebook))
