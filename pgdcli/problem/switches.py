"""Switch points: where a switching function of one coordinate has its kink or jump.

A coefficient such as ``max(t - 1, 0)`` or ``min(a, 0.5)`` is smooth on either side of a point
of its coordinate (``t = 1``, ``a = 0.5``) and not across it: a Chebyshev interpolant across the
point converges slowly, one with an element (or time slab) boundary there converges spectrally on
each side. :func:`switch_points` finds those points from the equations' one-coordinate functions:
the zeros of the arguments at which each switching function (:data:`~pgdcli.problem.trees.NON_SMOOTH`)
switches, located on a fine grid of the domain and refined by bisection. A switch of two or more
coordinates jointly (``max(t - a, 0)``) lies on a curve that no element boundary follows: it is
left to automatic resolution.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .general import is_general, tree_names, tree_of
from .trees import BINARY, NON_SMOOTH, evaluate_tree, map_leaves, t_add, t_neg, values_at

__all__ = ["switch_arguments", "switch_points", "with_switch_elements", "time_switches", "MAX_SWITCHES"]

#: Most switch points placed on one coordinate; beyond (``step(sin(50*t))``) none are placed and
#: automatic resolution decides.
MAX_SWITCHES = 16
#: Points of the grid on which sign changes are looked for.
SCAN_POINTS = 4097


def switch_arguments(tree: tuple) -> list[tuple]:
    """The trees whose sign changes are the switches of ``tree`` (``max(a, b)``: ``a - b``)."""
    found = []
    kind = tree[0]
    if kind == "call":
        name, args = tree[1], tree[2:]
        if name in NON_SMOOTH:
            if name in ("min", "max"):
                found.append(_difference(args[0], args[1]))
            elif name in ("clamp", "smoothstep"):
                x, ends = (args[0], args[1:]) if name == "clamp" else (args[2], args[:2])
                found.extend(_difference(x, end) for end in ends)
            elif name == "where":
                found.append(_difference(args[0][1], args[0][2]))
            else:  # abs, sign, step: the argument; atan2(y, x): y (its jump is at y = 0, x < 0)
                found.append(args[0])
        for child in args:  # a where() condition is a comparison node: its operands are searched too
            found.extend(switch_arguments(child))
    elif kind == "neg" or kind in BINARY:
        for child in tree[1:]:
            found.extend(switch_arguments(child))
    return found


def _difference(a: tuple, b: tuple) -> tuple:
    return t_add(a, t_neg(b))


def _zeros(tree: tuple, domain: tuple[float, float]) -> list[float]:
    """Interior points of ``domain`` where the one-variable ``tree`` changes sign."""
    low, high = domain
    x = np.linspace(low, high, SCAN_POINTS)
    with np.errstate(all="ignore"):
        values = np.asarray(evaluate_tree(tree, values_at(x)), dtype=float)
    sign = np.sign(values)
    zeros = [float(v) for v in x[1:-1][sign[1:-1] == 0]]
    brackets = np.nonzero(sign[:-1] * sign[1:] < 0)[0]
    for k in brackets:
        a, b = x[k], x[k + 1]
        sa = sign[k]
        for _ in range(60):
            mid = 0.5 * (a + b)
            with np.errstate(all="ignore"):
                sm = np.sign(float(evaluate_tree(tree, values_at(np.array(mid)))))
            if sm == 0:
                a = b = mid
                break
            a, b = (mid, b) if sm == sa else (a, mid)
        zeros.append(0.5 * (a + b))
    margin = 1e-9 * (high - low)
    return [z for z in zeros if low + margin < z < high - margin]


def switch_points(equations, coordinate: str, domain: tuple[float, float]) -> list[float]:
    """Sorted interior points of ``domain`` where a switching function of ``coordinate`` alone switches.

    Parameters
    ----------
    equations : iterable of Equation
        Their polynomials' coefficients are searched (one-coordinate factors of separated terms).
    coordinate : str
    domain : (float, float)

    Returns
    -------
    list of float
        At most :data:`MAX_SWITCHES` points, none closer than 1e-6 of the domain's length to another;
        empty when there are more.
    """
    points: list[float] = []
    for equation in equations:
        for sep in equation.polynomial.values():
            for term in sep.terms:
                for name, func in term.factors:
                    if name == coordinate:
                        for argument in switch_arguments(func.tree):
                            points.extend(_zeros(argument, domain))
    points.sort()
    merged: list[float] = []
    for p in points:
        if not merged or p - merged[-1] > 1e-6 * (domain[1] - domain[0]):
            merged.append(p)
    return merged if len(merged) <= MAX_SWITCHES else []


def with_switch_elements(coordinates: tuple, equations, time: str | None) -> tuple:
    """The coordinates with element boundaries added at the switch points of Chebyshev parameters."""
    out = []
    for c in coordinates:
        if c.role == "parameter" and c.name != time and c.discretization == "chebyshev":
            points = switch_points(equations, c.name, tuple(c.domain))
            if points:
                ends = list(c.breakpoints or c.domain)
                c = dataclasses.replace(c, breakpoints=tuple(sorted({*map(float, ends), *points})))
        out.append(c)
    return tuple(out)


def time_switches(equations, time: str | None, unknowns) -> list[tuple]:
    """The switch arguments of time (and parameters, not unknowns), as trees with ``('name', n)`` leaves.

    Those of the coefficients' functions of time (one-coordinate factors and non-separable parts) and
    of the functions of the unknowns whose argument holds no unknown: each node of the parameter grid
    meets their switches at times the formula gives, which the march lands on
    (:mod:`pgdcli.algorithms.switch_location`).
    """
    if time is None:
        return []
    found: list[tuple] = []
    for equation in equations:
        for monomial, sep in equation.polynomial.items():
            trees = [tree_of(atom) for atom in monomial if is_general(atom)]
            trees += [map_leaves(func.tree, lambda leaf, n=name: ("name", n))
                      for term in sep.terms for name, func in term.factors if name == time]
            trees += [map_leaves(joint.tree, lambda leaf: ("name", leaf[1])) for joint in sep.joints]
            for tree in trees:
                for argument in switch_arguments(tree):
                    names = tree_names(argument)
                    if time in names and not names & set(unknowns) and argument not in found:
                        found.append(argument)
    return found
