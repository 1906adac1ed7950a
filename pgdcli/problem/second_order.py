"""Second-order time derivatives, reduced to first-order systems.

An unknown ``x`` whose initial condition gives a value and a rate,
``initial: {value: x0, rate: v0}``, may appear as ``der(x, t, 2)`` in the
equations. It gets a *rate* unknown ``x_rate`` (:func:`rate_name`) with
``x_rate(t0) = v0``, and the system is rewritten exactly:

* ``der(x, t, 2)`` becomes ``der(x_rate)`` and ``der(x)`` becomes ``x_rate``,
  in every equation;
* the equation ``der(x) = x_rate`` is appended.

``der(x, t, 2) = -k*x - c*der(x)`` is thus the pair ``der(x_rate) = -k*x -
c*x_rate``, ``der(x) = x_rate``. Both solvers, the references, the codebook
and ``pgd query`` then see an ordinary first-order system whose unknowns are
the user's plus the rates (``x_rate`` is a field of the codebook; equations
may also name it directly).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping, Sequence

from .expressions import Atom, Polynomial, Separable

__all__ = ["RATE_SUFFIX", "INITIAL_KEYS", "rate_name", "reduce_to_first_order"]

RATE_SUFFIX = "_rate"
#: Keys of the initial condition of a second-order unknown.
INITIAL_KEYS = ("value", "rate")


def rate_name(name: str) -> str:
    """The name of the rate unknown of ``name`` (``x`` -> ``x_rate``)."""
    return name + RATE_SUFFIX


def _substitute(polynomial: Polynomial, rates: Mapping[str, str], time: str) -> Polynomial:
    """``der(x, t, 2)`` -> ``der(x_rate)``, ``der(x)`` -> ``x_rate`` for every ``x`` in ``rates``."""
    def atom_of(atom: Atom) -> Atom:
        if atom.unknown not in rates or atom.coordinate != time:
            return atom
        rate = rates[atom.unknown]
        return Atom(rate) if atom.order == 1 else Atom(rate, time, 1)

    return Polynomial({tuple(atom_of(a) for a in monomial): sep for monomial, sep in polynomial.items()})


def reduce_to_first_order(equations: Sequence, rates: Mapping[str, str], time: str | None) -> tuple[list, list[str]]:
    """The first-order system of equations with second time derivatives.

    Parameters
    ----------
    equations : sequence of pgdcli.problem.model.Equation
        As parsed (``der(x, t, 2)`` is ``Atom(x, t, 2)``).
    rates : mapping of str to str
        Second-order unknown -> its rate unknown (those declared with ``{value, rate}``).
    time : str or None

    Returns
    -------
    (list of Equation, list of str)
        The rewritten equations followed by one ``der(x) = x_rate`` per second-order unknown,
        and the first problem found as a one-line ``"<key path>: <message>"`` (empty when valid).
    """
    errors: list[tuple[str, str]] = []
    seconds = {}
    for eq in equations:
        for atom in eq.polynomial.atoms:
            if atom.coordinate == time and atom.order == 2:
                seconds.setdefault(atom.unknown, eq.index)
            if atom.unknown in rates.values() and atom.coordinate == time and atom.order > 0:
                x = next(u for u, r in rates.items() if r == atom.unknown)
                errors.append((f"equations[{eq.index}]", f"'{atom.text(time)}' in '{eq.text}': write the derivative "
                                                         f"of the rate of {x!r} as der({x}, {time}, 2)"))
    for unknown, index in seconds.items():
        if unknown not in rates:
            errors.append((f"equations[{index}]", f"der({unknown}, {time}, 2) needs the initial rate of {unknown!r}: "
                                                  f"write its initial condition as {{value: <x0>, rate: <v0>}}"))
    for unknown in rates:
        if unknown not in seconds:
            errors.append((f"unknowns.{unknown}.initial", f"an initial rate is given but der({unknown}, {time}, 2) "
                                                          f"appears in no equation; give 'initial' a single value"))
    if errors:
        return list(equations), [f"{path}: {text}" for path, text in errors[:1]]
    out = [replace(eq, polynomial=_substitute(eq.polynomial, rates, time)) for eq in equations]
    for unknown, rate in rates.items():
        polynomial = Polynomial({(Atom(unknown, time, 1),): Separable.constant(1.0),
                                 (Atom(rate),): Separable.constant(-1.0)})
        out.append(type(equations[0])(len(out), f"der({unknown}) = {rate}", polynomial))
    return out, []
