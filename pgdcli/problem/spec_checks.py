"""Checks of a spec that span its sections: which coordinates are space, and that the equations
determine the unknowns (every unknown in a steady system; one first-order time derivative per
equation, of every unknown, in a time-dependent one).

Part of :func:`pgdcli.problem.spec.parse_spec`; errors go through its
:class:`~pgdcli.problem.checker.Checker`.
"""

from __future__ import annotations

import dataclasses

from .checker import Checker
from .model import Equation

__all__ = ["assign_space_roles", "check_steady", "check_time_derivatives"]


def assign_space_roles(check: Checker, coordinates: tuple, unknowns: tuple, equations: tuple, time: str) -> tuple:
    """Coordinates with space derivatives are 'space'; each needs boundary conditions where it is
    differentiated twice, and boundary conditions need derivatives."""
    second: dict[tuple[str, str], int] = {}
    space = set()
    for eq in equations:
        for atom in eq.polynomial.atoms:
            if atom.order > 0 and atom.coordinate != time:
                space.add(atom.coordinate)
                if atom.order == 2:
                    second.setdefault((atom.unknown, atom.coordinate), eq.index)
    for u in unknowns:
        for coord in u.boundary:
            if coord not in space:
                raise check.error(f"unknowns.{u.name}.boundary.{coord}",
                                  f"{coord!r} has no derivative in the equations: it is a parameter, not space")
    for (unknown, coord), index in second.items():
        u = next(x for x in unknowns if x.name == unknown)
        if coord not in u.boundary:
            raise check.error(f"unknowns.{unknown}.boundary",
                              f"missing the conditions at both ends of {coord!r} (der({unknown}, {coord}, 2) "
                              f"appears in equations[{index}]), e.g. {{{coord}: {{low: 0, high: 0}}}}")
    return tuple(dataclasses.replace(c, role="space") if c.name in space else c for c in coordinates)


def check_steady(check: Checker, equations: list[Equation], unknowns: list[str]) -> None:
    """Without time every unknown must appear in some equation, or the system is singular."""
    appearing = {atom.unknown for equation in equations for atom in equation.polynomial.atoms}
    for name in unknowns:
        if name not in appearing:
            raise check.error("equations", f"unknown '{name}' appears in no equation of this steady problem "
                                           "(no time coordinate); each unknown needs an equation")


def check_time_derivatives(check: Checker, equations: list[Equation], unknowns: list[str], time: str) -> None:
    """First-order time derivatives only; one in every equation, of every unknown somewhere."""
    differentiated = set()
    for equation in equations:
        derivatives = [atom for atom in equation.polynomial.atoms if atom.order > 0 and atom.coordinate == time]
        for atom in derivatives:
            if atom.order > 1:
                raise check.error(
                    f"equations[{equation.index}]",
                    f"'{atom.text(time)}' in '{equation.text}': time derivatives of order 1 or 2 only"
                    " (write higher orders as first-order systems)",
                )
        if not derivatives:
            raise check.error(
                f"equations[{equation.index}]",
                f"no time derivative in '{equation.text}'; each equation must contain der(<unknown>)",
            )
        differentiated.update(atom.unknown for atom in derivatives)
    for name in unknowns:
        if name not in differentiated:
            raise check.error(
                "equations", f"unknown '{name}' never appears as der({name}); each unknown needs its time derivative"
            )
