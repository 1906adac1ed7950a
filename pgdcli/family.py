"""Families of specs: several codebooks built at once, one task each (a studio's codebook per character,
material or level).

:func:`solve_many` hands every problem to the executor in effect (or the one given) as one task: the
task parses the spec's text again where it runs (a cluster's worker need not see the spec's file)
and solves it with :func:`pgdcli.solve` in that worker's process. The results come back as the tasks
finish; a problem that fails (an error in its spec, a reference that cannot run, a bug) is reported in
its place and the others go on.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Iterator, Sequence

from . import executors

__all__ = ["solve_many", "FamilyFailure"]


@dataclass
class FamilyFailure:
    """A problem of a family that raised instead of returning a result.

    Attributes
    ----------
    error : Exception
        What it raised: a :class:`pgdcli.errors.PgdError` for bad input, anything else a bug.
    """

    error: Exception

    @property
    def message(self) -> str:
        return " ".join(str(self.error).split()) or type(self.error).__name__


def solve_many(problems: Sequence, *, executor=None, tolerance: float | None = None,
               relative_tolerance: float | None = None, max_modes: int | None = None) -> Iterator[tuple]:
    """Solve every problem, one task each; yield ``(index, result)`` as they finish.

    Parameters
    ----------
    problems : sequence of pgdcli.problem.spec.Problem
        Parsed specs (each with the text it was parsed from).
    executor : optional
        Where the tasks run (:func:`pgdcli.executors.as_executor`); default the executor in effect.
    tolerance, relative_tolerance, max_modes : optional
        Overrides for every problem, as :func:`pgdcli.solve` takes them.

    Yields
    ------
    (int, SolveResult or FamilyFailure)
        The problem's index in ``problems`` and its result, or what it raised.
    """
    runner = executors.current() if executor is None else executors.as_executor(executor)
    overrides = {"tolerance": tolerance, "relative_tolerance": relative_tolerance, "max_modes": max_modes}
    texts = [(p.source_text, p.source, p.name) for p in problems]
    for i, outcome in runner.as_completed(partial(_solve_text, overrides), texts):
        try:
            yield i, outcome.result()
        except Exception as exc:  # noqa: BLE001 - one problem's failure is its row, the others go on
            yield i, FamilyFailure(exc)


def _solve_text(overrides: dict, spec: tuple):
    """A task: the spec ``(text, source, name)`` parsed again and solved here (serially)."""
    from .driver import solve
    from .problem.spec import parse_spec

    text, source, name = spec
    problem = parse_spec(text, source=source, name=name, allow_nonlinear=True)
    with executors.using(executors.SERIAL):  # a task does not hand out tasks of its own
        return solve(problem, **overrides)
