"""``pgd verify``: a codebook against an independent reference (:mod:`pgdcli.checks.verify`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from ..limits import DEFAULT_CHECK_SECONDS
from .cluster_options import cluster_options, open_executor, scheduler_given
from .formats import VERIFY
from .group import Failed, cli, format_option, run_command, stderr_console


class _MethodChoice(click.Choice):
    """Methods matched in any case and named in an error as the help spells them (click names them
    lowercased: 'dop853', 'rk45')."""

    def get_invalid_choice_message(self, value, ctx) -> str:
        return f"{value!r} is not one of {', '.join(map(repr, self.choices))}."


VERIFY_METHODS = ("DOP853", "RK45", "Radau", "BDF", "LSODA")  # pgdcli.checks.reference.METHODS (no numpy import here)


@VERIFY.register("text", "table on stderr")
def write_nothing(report) -> None:
    """Nothing on stdout: the tables are printed on stderr with the progress (none with --quiet)."""


@VERIFY.register("json", "the report as JSON on stdout (keys in docs/verify.md)")
def write_json(report) -> None:
    click.echo(json.dumps(report.to_dict(), indent=2))


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
@click.option("--method", type=_MethodChoice(VERIFY_METHODS, case_sensitive=False), default=None,
              metavar="[" + "|".join(VERIFY_METHODS) + "]",
              help="solve_ivp method of the reference [default: DOP853, or Radau where the problem is stiff, as the "
                   "error gate decides; BDF with space coordinates].")
@click.option("--rtol", type=click.FloatRange(0, 1, min_open=True, max_open=True),
              help="Relative tolerance of the reference [default: 1e-12; 1e-10 with space coordinates].")
@click.option("--atol", type=click.FloatRange(0, 1, min_open=True, max_open=True),
              help="Absolute tolerance of the reference [default: 1e-12].")
@click.option("-j", "--jobs", type=click.IntRange(min=1), metavar="N",
              help="Worker processes [default: all cores]; 1 runs in this process.")
@click.option("--max-error", type=click.FloatRange(min=0), metavar="TOL",
              help="Exit 1 when the max absolute error of an unknown exceeds TOL [default: gate on the "
                   "codebook's own tolerance].")
@click.option("--max-rel-error", type=click.FloatRange(min=0), metavar="TOL",
              help="Exit 1 when the max relative error (max abs error / max |reference|) of an unknown exceeds TOL.")
@click.option("--max-seconds", type=click.FloatRange(min=0, min_open=True), default=DEFAULT_CHECK_SECONDS,
              show_default=True, metavar="S",
              help="Time budget of the reference integrations: at S seconds the check stops, the points not "
                   "integrated yet are reported as not checked, and the exit status is 1.")
@format_option(VERIFY)
@click.option("-q", "--quiet", is_flag=True, help="No progress bar or table on stderr.")
@cluster_options("the reference's chunks of parameter points")
@click.pass_context
def verify_command(ctx, codebook, samples, sampling, seed, points, n_times, method, rtol, atol, jobs, max_error,
                   max_rel_error, max_seconds, fmt, quiet, scheduler, workers):
    """Check CODEBOOK against an independent reference of its own problem.

    The problem stored in the codebook is integrated again with scipy's
    solve_ivp at sample points of the parameter box (scrambled Sobol plus
    every corner), and the codebook is compared with it at every time node
    and at random times. A table of the errors per unknown goes to stderr.

    The gate: without --max-error or --max-rel-error, the codebook's own
    tolerance (|error| <= tolerance + relative_tolerance |u| at every checked
    point); with either, those thresholds.

    Exit status: 0 passed; 1 a reference integration failed, an error
    exceeds the gate (for CI), or the time budget (--max-seconds) ran out
    first; 2 invalid input.

    \b
      pgd verify codebooks/spring.h5
      pgd verify codebooks/spring.h5 --max-error 1e-8 --format json > verify.json
      pgd verify codebooks/spring.h5 --points points.csv --times 100 --method Radau
    """
    if jobs is not None and (workers is not None or scheduler_given(ctx, scheduler)[0] is not None):
        raise click.UsageError("--jobs runs local processes; with --scheduler or --workers the cluster's workers "
                               "run the reference")
    with open_executor(ctx, scheduler, workers, quiet) as executor:
        run_command(_verify, codebook, samples, sampling, seed, points, n_times, method, rtol, atol, jobs, max_error,
                    max_rel_error, max_seconds, fmt, quiet, executor)


def _verify(codebook, samples, sampling, seed, points, n_times, method, rtol, atol, jobs, max_error, max_rel_error,
            max_seconds, fmt, quiet, executor=None):
    from ..checks.verify import verify as verify_codebook

    for hint, value in (("'--max-error'", max_error), ("'--max-rel-error'", max_rel_error)):
        if value is not None and not math.isfinite(value):
            raise click.BadParameter(f"expected a finite number >= 0, got {value}", param_hint=hint)
    method = None if method is None else next(m for m in VERIFY_METHODS if m.lower() == method.lower())
    options = dict(samples=samples, sampling=sampling, seed=seed, points=points, times=n_times, method=method,
                   rtol=rtol, atol=atol, jobs=jobs, max_error=max_error, max_rel_error=max_rel_error,
                   max_seconds=max_seconds, executor=executor)
    console = None if quiet else stderr_console()
    if console is None:
        report = verify_codebook(codebook, **options)
    else:
        report = _verify_with_progress(console, codebook, verify_codebook, options)
        for renderable in _verify_tables(report, max_error, max_rel_error):
            console.print(renderable)
    VERIFY.writer(fmt)(report)
    reasons = report.violations(max_error, max_rel_error)
    if reasons:
        raise Failed(f"{codebook}: verification failed: " + "; ".join(reasons))


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


def _events_table(report, number):
    """The event times' errors (a codebook with events)."""
    from rich.table import Table

    events = Table(title="event times against scipy's event location", title_justify="left")
    for column in ("event", "max abs error", "error / tolerance", "worst at"):
        events.add_column(column, justify="left" if column in ("event", "worst at") else "right")
    for name, check in report.events.items():
        events.add_row(name, number(check.error), "n/a" if not math.isfinite(check.ratio) else f"{check.ratio:.3g}",
                       ", ".join(f"{k}={v:.6g}" for k, v in check.where.items()) or "-")
    return events


def _verify_tables(report, max_error, max_rel_error) -> list:
    from rich.table import Table

    from ..checks.check import ordinal

    def number(value):
        return "n/a" if not math.isfinite(value) else f"{value:.3e}"

    s = report.settings
    runners = f"{s['jobs']} job(s)" if "cluster" not in s else f"{s['jobs']} Dask worker(s) at {s['cluster']}"
    if s["sampling"] == "points":
        where = f"{s['parameter_points']} parameter points from {s['points_file'] or 'the given points'}"
    else:
        capped = f" (capped at {s['corners']})" if s["corners"] < s["corners_total"] else ""
        where = (f"{s['parameter_points']} parameter points ({s['samples']} {s['sampling']} + "
                 f"{s['corners_total']} corners{capped})")
    if report.time is None:
        caption = f"{where}, steady; reference: Chebyshev collocation, sparse direct solve, {runners}, "
    else:
        nodes = (f"{s['time_nodes']} of {s['time_nodes_total']} nodes, every {ordinal(s['time_node_stride'])}"
                 if "time_nodes_total" in s else f"{s['time_nodes']} nodes")
        caption = (f"{where} x {s['times']} times ({nodes} + {s['random_times']} random); "
                   f"reference {s['method']} rtol {s['rtol']:.0e} atol {s['atol']:.0e}, {runners}, ")
    caption += f"{report.wall_time:.2f} s. rel error = max abs error / max |reference| of the unknown."
    if report.tolerance is not None:
        relative = f" + {report.relative_tolerance:.3g} |reference|" if report.relative_tolerance else ""
        caption += f" error / tolerance = max of |error| / ({report.tolerance:.3g}{relative}), the codebook's own."
    table = Table(title=f"pgd verify: {report.problem}", title_justify="left", caption=caption,
                  caption_justify="left")
    ratio = report.tolerance is not None
    columns = ("unknown", "max abs error", "max rel error", "RMS error", "max |reference|") \
        + (("error / tolerance",) if ratio else ()) + ("worst at",)
    for column in columns:
        table.add_column(column, justify="left" if column in ("unknown", "worst at") else "right")
    for name, stats in report.unknowns.items():
        at = ", ".join(f"{k}={v:.6g}" for k, v in stats.where.items()) if math.isfinite(stats.max_abs_error) else "n/a"
        cells = [number(stats.max_abs_error), number(stats.max_rel_error), number(stats.rms_error),
                 number(stats.reference_scale)]
        if ratio:
            cells.append("n/a" if not math.isfinite(stats.tolerance_ratio) else f"{stats.tolerance_ratio:.3g}")
        table.add_row(name, *cells, at)
    out: list = [table]
    if report.events:
        out.append(_events_table(report, number))
    if report.not_checked:
        out.append(f"[bold red]stopped at the time budget of {s['max_seconds']:g} s[/]: {report.not_checked} of "
                   f"{s['parameter_points']} parameter points not checked (raise --max-seconds)")
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
    verdict = "[green]passed[/]" if report.passed(max_error, max_rel_error) else "[red]FAILED[/]"
    out.append(f"{verdict} (gate: {report.gate_text(max_error, max_rel_error)})")
    return out
