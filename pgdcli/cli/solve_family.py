"""``pgd solve`` of several specs, or of a folder of them: a family built one spec per task.

Every spec is read and checked here first; one that is invalid is reported in its row and the others
are built. Codebooks go where each spec says (``output``, else ``codebooks/<name>.h5``), or into the
folder ``--output`` names; two specs writing the same file are refused before any work. The table
(stderr) or the JSON list (stdout, ``--format json``) has one row per spec; the exit status is 0
when every codebook was written, 2 when a spec was invalid or failed, else 1.
"""

from __future__ import annotations

import math
from pathlib import Path

import click

from ..errors import PgdError
from ..family import FamilyFailure, solve_many
from .formats import SOLVE
from .group import Failed, stderr_console, warn
from .outputs import prepare_output
from .text import human_size

__all__ = ["family_specs", "solve_family"]

SUFFIXES = (".yaml", ".yml")


def family_specs(specs) -> list[Path] | None:
    """The spec files of a family (each file given, then every ``*.yaml``/``*.yml`` of a folder, sorted);
    None for one spec file (the plain ``pgd solve``)."""
    specs = [Path(p) for p in specs]
    if len(specs) == 1 and not specs[0].is_dir():
        return None
    files: list[Path] = []
    for path in specs:
        if path.is_dir():
            found = sorted(f for f in path.iterdir() if f.suffix.lower() in SUFFIXES and f.is_file())
            if not found:
                raise PgdError(f"{path}: no spec (*.yaml, *.yml) in this folder")
            files += found
        else:
            files.append(path)
    seen: set = set()
    for path in files:
        key = path.resolve()
        if key in seen:
            raise PgdError(f"{path}: spec given twice")
        seen.add(key)
    return files


def solve_family(specs: list[Path], output, tolerance, relative_tolerance, max_modes, keep_inaccurate, fmt, quiet,
                 cluster) -> None:
    """Build every spec (:func:`pgdcli.family.solve_many`), write the codebooks, sum up."""
    _check_overrides(tolerance, relative_tolerance, max_modes)
    rows = [{"spec": str(path)} for path in specs]
    problems = _checked_problems(specs, rows, output, tolerance, relative_tolerance, max_modes)
    console = None if quiet else stderr_console()
    todo = [i for i, row in enumerate(rows) if "error" not in row]
    with cluster() as executor:
        outcomes = solve_many([problems[i] for i in todo], executor=executor, tolerance=tolerance,
                              relative_tolerance=relative_tolerance, max_modes=max_modes)
        if console is None:
            for j, outcome in outcomes:
                _record(rows[todo[j]], outcome, keep_inaccurate)
        else:
            _with_progress(console, outcomes, rows, todo, keep_inaccurate)
    if console is not None:
        for renderable in _family_table(rows):
            console.print(renderable)
    SOLVE.writer(fmt)(rows)
    failed = [row for row in rows if row["status"] != "written"]
    if failed:
        listed = ", ".join(f"{row['spec']} ({row['status']})" for row in failed)
        message = f"{len(failed)} of {len(rows)} specs without a codebook: {listed}"
        if any(row["status"] in ("invalid", "failed") for row in failed):
            raise PgdError(message)
        raise Failed(message)


def _check_overrides(tolerance, relative_tolerance, max_modes) -> None:
    checks = (("'--tolerance'", tolerance, lambda v: 0.0 < v < 1.0, "a number in (0, 1)"),
              ("'--relative-tolerance'", relative_tolerance, lambda v: 0.0 <= v < 1.0, "a number in [0, 1)"),
              ("'--max-modes'", max_modes, lambda v: v >= 1, "an integer >= 1"))
    for hint, value, good, expected in checks:
        if value is not None and not good(value):
            raise click.BadParameter(f"expected {expected}, got {value}", param_hint=hint)


def _checked_problems(specs, rows, output, tolerance, relative_tolerance, max_modes) -> dict:
    """Each spec read and checked (:func:`pgdcli.driver.check_solvable`), its target chosen and probed;
    an invalid spec's row gets its error. Two specs writing one file: PgdError, before any work."""
    from ..driver import check_solvable
    from ..problem.spec import load_spec
    if output is not None and Path(output).suffix.lower() in (".h5", ".hdf5"):
        raise PgdError(f"--output {output}: with several specs, --output names the folder of their codebooks")
    problems, targets = {}, {}
    for i, path in enumerate(specs):
        try:
            problem = load_spec(path)
            s = problem.solver
            check_solvable(problem, s.tolerance if tolerance is None else tolerance,
                           s.relative_tolerance if relative_tolerance is None else relative_tolerance,
                           s.max_modes if max_modes is None else max_modes)
            target = Path(output) / f"{problem.name}.h5" if output is not None else Path(problem.output)
            prepare_output(target, "--output" if output is not None else f"{path}: output")
        except PgdError as exc:
            rows[i].update(status="invalid", error=" ".join(str(exc).split()))
            continue
        other = targets.get(target.resolve())
        if other is not None:
            raise PgdError(f"{specs[other]} and {path} would both write {target}; give them different names or "
                           f"outputs")
        targets[target.resolve()] = i
        problems[i] = problem
        rows[i].update(problem=problem.name, output=str(target))
    return problems


def _with_progress(console, outcomes, rows, todo, keep_inaccurate) -> None:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("specs {task.fields[status]}"), TimeElapsedColumn(), console=console) as progress:
        task = progress.add_task("solving the family", total=len(todo), status="")
        for done, (j, outcome) in enumerate(outcomes, 1):
            row = rows[todo[j]]
            _record(row, outcome, keep_inaccurate)
            progress.update(task, completed=done, status=f"(last: {row['spec']}, {row['status']})")


def _record(row: dict, outcome, keep_inaccurate: bool) -> None:
    """A spec's row from its result (its codebook written, when it is to be kept) or its failure."""
    if isinstance(outcome, FamilyFailure):
        kind = "" if isinstance(outcome.error, PgdError) else "internal error: "
        row.update(status="failed", error=kind + outcome.message)
        return
    for warning in outcome.warnings:
        warn(f"{row['spec']}: {warning}")
    report = outcome.codebook.report
    keep = outcome.converged or (keep_inaccurate and outcome.accurate is False)
    row.update(converged=bool(outcome.converged), accurate=outcome.accurate, message=outcome.message,
               tolerance=float(report.get("tolerance", math.nan)), wall_time=float(outcome.wall_time),
               check_error=_finite_or_none(report.get("check_error", math.nan)),
               check_ratio=_finite_or_none(report.get("check_ratio", math.nan)))
    if keep:
        outcome.codebook.save(row["output"])
        row["size_bytes"] = Path(row["output"]).stat().st_size
    row["status"] = ("written" if outcome.converged else "written, inaccurate" if keep else
                     "tolerance not met" if outcome.accurate is False else "not converged")


def _finite_or_none(value) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def _family_table(rows: list[dict]) -> list:
    """The table of the family (one row a spec), then why each spec without a codebook has none."""
    from rich.markup import escape
    from rich.table import Table


    table = Table(title=f"pgd solve: {len(rows)} specs", title_justify="left")
    for column, justify in (("spec", "left"), ("status", "left"), ("error / tolerance", "right"),
                            ("time", "right"), ("codebook", "left")):
        table.add_column(column, justify=justify, overflow="fold")
    colours = {"written": "green", "invalid": "red", "failed": "red"}
    reasons = []
    for row in rows:
        ratio = row.get("check_ratio")
        status = f"[{colours.get(row['status'], 'yellow')}]{escape(row['status'])}[/]"
        codebook = f"{escape(row['output'])} ({human_size(row['size_bytes'])})" if "size_bytes" in row else ""
        table.add_row(escape(row["spec"]), status, "" if ratio is None else f"{ratio:.2f}",
                      f"{row['wall_time']:.1f} s" if "wall_time" in row else "", codebook)
        if row["status"] != "written":
            reason = row.get("error") or row.get("message", "")
            prefix = f"{row['spec']}: "  # a spec's own errors name it already
            reasons.append(f"{escape(row['spec'])}: {escape(reason.removeprefix(prefix))}")
    return [table, *reasons]
