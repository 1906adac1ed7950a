"""Separated terms: functions of one coordinate and their products.

:class:`Func1D` is a function of one coordinate (or a constant) as an expression tree
(:mod:`pgdcli.problem.trees`, leaf ``('var',)``); :class:`SepTerm` is a product
``coef * prod_j f_j(x_j)`` with at most one factor per coordinate. Sums of terms and the
non-separable parts are :mod:`pgdcli.problem.separable`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from .trees import evaluate_tree, format_number, map_leaves, num, num_value, render_text, t_div, t_mul, t_pow, values_at

__all__ = ["Func1D", "SepTerm", "term_text", "term_tree", "named_variable", "join_signed", "normalize_terms"]

_VAR: tuple = ("var",)


@dataclass(frozen=True)
class Func1D:
    """A function of one coordinate, or a constant, as an expression tree.

    Attributes
    ----------
    coordinate : str or None
        Name of the coordinate; None for a constant.
    tree : tuple
        ``('num', value)``, ``('var',)``, ``('call', fname, child)``,
        ``('neg', a)`` or ``(op, a, b)`` with op in add, sub, mul, div, pow.
    """

    coordinate: str | None
    tree: tuple = _VAR

    def __call__(self, x: np.ndarray | float) -> np.ndarray:
        """Evaluate at the points x; the result has the shape of x."""
        x = np.asarray(x, dtype=float)
        result = evaluate_tree(self.tree, values_at(x))
        # never hand back the caller's own array for the identity function
        return x.copy() if result is x else np.asarray(result, dtype=float)

    def __str__(self) -> str:
        return render_text(self.tree, self.coordinate or "?")

    @property
    def is_constant(self) -> bool:
        """True if the tree is a single number."""
        return self.tree[0] == "num"

    def times(self, other: Func1D) -> Func1D:
        """Product with a function of the same coordinate (or a constant)."""
        coordinate = self.coordinate or other.coordinate
        if other.coordinate not in (None, coordinate):
            raise ValueError(f"cannot merge functions of {self.coordinate!r} and {other.coordinate!r}")
        return Func1D(coordinate, t_mul(self.tree, other.tree))

    def reciprocal(self) -> Func1D:
        """``1/f``."""
        return Func1D(self.coordinate, t_div(num(1.0), self.tree))

    def power(self, exponent: float) -> Func1D:
        """``f**exponent``."""
        return Func1D(self.coordinate, t_pow(self.tree, num(exponent)))

    def apply(self, function: str) -> Func1D:
        """``function(f)`` for a name of :data:`FUNCTIONS`."""
        return Func1D(self.coordinate, ("call", function, self.tree))


@dataclass(frozen=True)
class SepTerm:
    """One separable product ``coef * prod_j f_j(x_j)``.

    Attributes
    ----------
    coef : float
    factors : tuple of (str, Func1D)
        Sorted by coordinate name, each coordinate at most once, each function
        a function of its coordinate. No factors means a constant term.
    """

    coef: float
    factors: tuple[tuple[str, Func1D], ...] = ()

    def __post_init__(self) -> None:
        factors = tuple(sorted(self.factors, key=lambda item: item[0]))
        names = [name for name, _ in factors]
        if len(set(names)) != len(names):
            raise ValueError(f"coordinate repeated in factors: {names}")
        for name, func in factors:
            if func.coordinate != name:
                raise ValueError(f"factor of {name!r} is a function of {func.coordinate!r}")
        object.__setattr__(self, "coef", float(self.coef))
        object.__setattr__(self, "factors", factors)

    @property
    def coordinates(self) -> frozenset[str]:
        """Coordinates the term depends on."""
        return frozenset(name for name, _ in self.factors)

    def evaluate(self, /, **values: np.ndarray) -> np.ndarray:
        """``coef * prod_j f_j(values[x_j])`` with numpy broadcasting."""
        result: np.ndarray | float = self.coef
        for name, func in self.factors:
            result = result * func(values[name])
        return np.asarray(result, dtype=float)

    def __mul__(self, other: SepTerm) -> SepTerm:
        if not isinstance(other, SepTerm):
            return NotImplemented
        merged = dict(self.factors)
        coef = self.coef * other.coef
        for name, func in other.factors:
            # same coordinate on both sides: one function, so the term stays separated
            merged[name] = merged[name].times(func) if name in merged else func
            if merged[name].is_constant:  # e.g. k * (1/k): the number moves to the coefficient
                coef *= merged.pop(name).tree[1]
        return SepTerm(coef, tuple(merged.items()))

    def scaled(self, factor: float) -> SepTerm:
        """The term times a number."""
        return SepTerm(self.coef * factor, self.factors)

    def __str__(self) -> str:
        return term_text(self, signed=True)


def term_text(term: SepTerm, signed: bool) -> str:
    """Text of a term; with signed=False the sign of the coefficient is left out."""
    numerators, denominators = [], []
    for name, func in term.factors:
        tree = func.tree
        if tree[0] == "div" and num_value(tree[1]) == 1:
            denominators.append((tree[2], name))
        else:
            numerators.append(render_text(tree, name, 2))
    coef = abs(term.coef)
    if coef != 1 or not numerators:
        numerators.insert(0, format_number(coef))
    text = "*".join(numerators)
    if len(denominators) == 1:
        text += "/" + render_text(*denominators[0], 3)
    elif denominators:
        text += "/(" + "*".join(render_text(tree, name, 2) for tree, name in denominators) + ")"
    return "-" + text if signed and term.coef < 0 else text



def named_variable(tree: tuple, coordinate: str) -> tuple:
    """A one-coordinate tree with its variable named: ``('var',)`` -> ``('coord', coordinate)``."""
    return map_leaves(tree, lambda leaf: ("coord", coordinate) if leaf == _VAR else leaf)


def term_tree(term: SepTerm) -> tuple:
    """A separable term as one joint tree (coordinates named)."""
    tree = num(term.coef)
    for name, func in term.factors:
        tree = t_mul(tree, named_variable(func.tree, name))
    return tree



def join_signed(pieces: Iterable[tuple[bool, str]]) -> str:
    """Join (negative, text) pieces as 'a + b - c'."""
    out = ""
    for negative, text in pieces:
        if not out:
            out = "-" + text if negative else text
        else:
            out += (" - " if negative else " + ") + text
    return out or "0"


def normalize_terms(terms: Iterable[SepTerm]) -> tuple[SepTerm, ...]:
    """Combine terms with equal factors and drop zero terms (first-appearance order)."""
    coefs: dict[tuple, float] = {}
    for term in terms:
        coefs[term.factors] = coefs.get(term.factors, 0.0) + term.coef
    return tuple(SepTerm(coef, factors) for factors, coef in coefs.items() if coef != 0)


