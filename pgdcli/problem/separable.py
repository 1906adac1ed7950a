"""Sums of separated terms, and the non-separable parts kept as trees.

:class:`Separable` is a sum of :class:`~pgdcli.problem.terms.SepTerm` (``terms``) plus
non-separable parts (``joints``); a :class:`Joint` is ``SepTerm * g(x_a, x_b, ...)`` with ``g``
an expression tree of two or more coordinates (leaves ``('coord', name)``), which the solvers
separate numerically on their nodes (:mod:`pgdcli.discretization.separate`) and the references
evaluate directly.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Iterable, Mapping

import numpy as np

from .terms import Func1D, SepTerm, join_signed, named_variable, normalize_terms, term_text, term_tree
from .trees import (evaluate_tree, leaf_names, map_leaves, num, render_text, t_add, t_mul, values_at,
                    values_by_name)

__all__ = ["Joint", "Separable", "TimeSplit", "as_separable", "merge_to_function", "constant_tree_value", "joint_of",
           "tree_coordinates"]


def tree_coordinates(tree: tuple) -> frozenset[str]:
    """Coordinates named in a joint tree."""
    return leaf_names(tree, "coord")


@dataclass(frozen=True)
class Joint:
    """A non-separable part of a coefficient: ``term * g(x_a, x_b, ...)``.

    ``g`` depends on two or more coordinates and is kept as an expression tree
    (leaves ``('coord', name)``), evaluated vectorized by :meth:`evaluate`; the
    solvers separate it numerically on their nodes (:mod:`pgdcli.discretization.coefficients`).
    One-coordinate factors of other coordinates stay apart in ``term``, so that
    ``F*sin(w*t)`` is separated over (w, t) only.

    Attributes
    ----------
    term : SepTerm
        The coefficient and the one-coordinate factors of coordinates not in ``tree``.
    tree : tuple
        The joint function.
    """

    term: SepTerm
    tree: tuple

    @classmethod
    def make(cls, term: SepTerm, tree: tuple) -> Joint:
        """The product ``term * tree``, with the term's factors of the tree's coordinates folded into the tree."""
        inside = tree_coordinates(tree)
        kept = []
        for name, func in term.factors:
            if name in inside:
                tree = t_mul(tree, named_variable(func.tree, name))
            else:
                kept.append((name, func))
        return cls(SepTerm(term.coef, tuple(kept)), tree)

    @property
    def tree_coordinates(self) -> frozenset[str]:
        """Coordinates of the joint function (at least two)."""
        return tree_coordinates(self.tree)

    @property
    def coordinates(self) -> frozenset[str]:
        return self.term.coordinates | self.tree_coordinates

    def evaluate(self, /, **values: np.ndarray) -> np.ndarray:
        """The value with numpy broadcasting; values maps coordinate names to arrays."""
        return self.term.evaluate(**values) * self.evaluate_tree(values)

    def evaluate_tree(self, values: Mapping[str, np.ndarray]) -> np.ndarray:
        """The joint function alone (without ``term``) at broadcast arrays of its coordinates."""
        return np.asarray(evaluate_tree(self.tree, values_by_name(values)), dtype=float)

    def with_value(self, coordinate: str, value: float) -> Joint:
        """The joint function with one coordinate fixed at a number (the factor ``term`` unchanged)."""
        fixed = map_leaves(self.tree, lambda leaf: num(value) if leaf == ("coord", coordinate) else leaf)
        return Joint(self.term, fixed)

    def function_text(self) -> str:
        """Text of the joint function alone, e.g. ``sin(w*t)``."""
        return render_text(self.tree, "?")

    def scaled(self, factor: float) -> Joint:
        return Joint(self.term.scaled(factor), self.tree)

    def times_term(self, other: SepTerm) -> Joint:
        return Joint.make(self.term * other, self.tree)

    def __mul__(self, other: Joint) -> Joint:
        if not isinstance(other, Joint):
            return NotImplemented
        return Joint.make(self.term * other.term, t_mul(self.tree, other.tree))

    def __str__(self) -> str:
        text = term_text(SepTerm(abs(self.term.coef), self.term.factors), signed=False)
        inner = render_text(self.tree, "?", 2)
        text = inner if text == "1" else f"{text}*{inner}"
        return "-" + text if self.term.coef < 0 else text


def _normalize_joints(joints: Iterable[Joint]) -> tuple[Joint, ...]:
    """Combine joints with equal factors and trees, drop zero ones (first-appearance order)."""
    coefs: dict[tuple, float] = {}
    for joint in joints:
        key = (joint.term.factors, joint.tree)
        coefs[key] = coefs.get(key, 0.0) + joint.term.coef
    return tuple(Joint(SepTerm(coef, factors), tree) for (factors, tree), coef in coefs.items() if coef != 0)



@dataclass(frozen=True, eq=False)
class Separable:
    """A sum of separable products (:class:`SepTerm`).

    Like terms are combined and zero terms dropped on construction; equality
    does not depend on the order of the terms.
    """

    terms: tuple[SepTerm, ...] = ()
    #: non-separable parts (functions of two or more coordinates jointly), kept as trees
    joints: tuple[Joint, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "terms", normalize_terms(self.terms))
        object.__setattr__(self, "joints", _normalize_joints(self.joints))

    # -- constructors ----------------------------------------------------------------------
    @classmethod
    def constant(cls, value: float) -> Separable:
        """The constant ``value``."""
        return cls((SepTerm(value),))

    @classmethod
    def variable(cls, coordinate: str) -> Separable:
        """The coordinate itself."""
        return cls((SepTerm(1.0, ((coordinate, Func1D(coordinate)),)),))

    @classmethod
    def of_function(cls, func: Func1D) -> Separable:
        """One function of one coordinate (a constant Func1D gives a constant)."""
        if func.coordinate is None:
            return cls.constant(constant_tree_value(func.tree))
        return cls((SepTerm(1.0, ((func.coordinate, func),)),))

    # -- properties ------------------------------------------------------------------------
    @property
    def coordinates(self) -> frozenset[str]:
        """Coordinates any term depends on."""
        return frozenset().union(*(term.coordinates for term in (*self.terms, *self.joints)))

    @property
    def is_zero(self) -> bool:
        return not self.terms and not self.joints

    @property
    def is_separated(self) -> bool:
        """True without non-separable parts: a sum of products of one-coordinate functions."""
        return not self.joints

    def separated_part(self) -> Separable:
        """The sum of the separable terms alone (the joints left out)."""
        return Separable(self.terms)

    @property
    def constant_value(self) -> float | None:
        """The number if the sum is a constant (0.0 for zero), else None."""
        if self.joints:
            return None
        if self.is_zero:
            return 0.0
        if len(self.terms) == 1 and not self.terms[0].factors:
            return self.terms[0].coef
        return None

    # -- evaluation ------------------------------------------------------------------------
    def evaluate(self, /, **values: np.ndarray) -> np.ndarray:
        """Evaluate with coordinate name -> array (numpy broadcasting).

        The result has the broadcast shape of all given values, also for a
        constant. A coordinate a term needs but not given raises KeyError.
        """
        shape = np.broadcast_shapes(*(np.shape(v) for v in values.values()))
        result = np.zeros(shape)
        for term in (*self.terms, *self.joints):
            result = result + term.evaluate(**values)
        return result

    # -- arithmetic ------------------------------------------------------------------------
    def __add__(self, other: Separable | float) -> Separable:
        other = as_separable(other)
        if other is None:
            return NotImplemented
        return Separable(self.terms + other.terms, self.joints + other.joints)

    __radd__ = __add__

    def __neg__(self) -> Separable:
        return self * -1.0

    def __sub__(self, other: Separable | float) -> Separable:
        other = as_separable(other)
        if other is None:
            return NotImplemented
        return self + (-other)

    def __rsub__(self, other: float) -> Separable:
        other = as_separable(other)
        if other is None:
            return NotImplemented
        return other + (-self)

    def __mul__(self, other: Separable | float) -> Separable:
        if isinstance(other, numbers.Real) and not isinstance(other, bool):
            factor = float(other)
            return Separable(tuple(term.scaled(factor) for term in self.terms),
                             tuple(joint.scaled(factor) for joint in self.joints))
        if not isinstance(other, Separable):
            return NotImplemented
        joints = [j.times_term(t) for j in self.joints for t in other.terms]
        joints += [j.times_term(t) for j in other.joints for t in self.terms]
        joints += [a * b for a in self.joints for b in other.joints]
        return Separable(tuple(a * b for a in self.terms for b in other.terms), tuple(joints))

    __rmul__ = __mul__

    def __truediv__(self, other: float) -> Separable:
        if isinstance(other, numbers.Real) and not isinstance(other, bool):
            return self * (1.0 / float(other))
        return NotImplemented

    # -- comparison, text ------------------------------------------------------------------
    def _key(self) -> dict:
        key = {term.factors: term.coef for term in self.terms}
        key.update({(j.term.factors, j.tree): j.term.coef for j in self.joints})
        return key

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Separable):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(frozenset(self._key().items()))

    def __str__(self) -> str:
        pieces = [(term.coef < 0, term_text(term, signed=False)) for term in self.terms]
        pieces += [(j.term.coef < 0, str(j.scaled(-1.0) if j.term.coef < 0 else j)) for j in self.joints]
        return join_signed(pieces)

    def tree(self) -> tuple:
        """The whole sum as one expression tree with named coordinates (leaves ``('coord', name)``)."""
        tree = num(0.0)
        for term in self.terms:
            tree = t_add(tree, term_tree(term))
        for joint in self.joints:
            tree = t_add(tree, t_mul(term_tree(joint.term), joint.tree))
        return tree


def as_separable(value: object) -> Separable | None:
    if isinstance(value, Separable):
        return value
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return Separable.constant(float(value))
    return None


def constant_tree_value(tree: tuple) -> float:
    """Value of a tree without variable (evaluated once, at a dummy point)."""
    return float(evaluate_tree(tree, values_at(np.zeros(()))))


def merge_to_function(sep: Separable) -> Func1D | None:
    """Merge a sum that depends on at most one coordinate into one :class:`Func1D`.

    Parameters
    ----------
    sep : Separable

    Returns
    -------
    Func1D or None
        ``sum_i c_i f_i(x)`` as a single function of x (coordinate None if the
        sum is constant), or None if the terms depend on two or more
        coordinates in total.
    """
    coordinates = sep.coordinates
    if len(coordinates) > 1 or sep.joints:
        return None
    coordinate = next(iter(coordinates), None)
    tree = num(0.0)
    for term in sep.terms:
        piece = num(term.coef)
        for _, func in term.factors:
            piece = t_mul(piece, func.tree)
        tree = t_add(tree, piece)
    return Func1D(coordinate, tree)


def joint_of(tree: tuple) -> Separable:
    """A non-separable function of coordinates (a tree with named coordinates) as a Separable."""
    if len(tree_coordinates(tree)) < 2:  # cannot happen for the parser's callers: kept as a guard
        raise ValueError(f"a joint function needs two or more coordinates: {tree}")
    return Separable((), (Joint(SepTerm(1.0), tree),))


class TimeSplit:
    """A coefficient at many times on fixed points: ``steady + sum_k f_k(t) g_k + joints(t)``.

    The parts free of time (``steady`` and each ``g_k``, the terms sharing the time function
    ``f_k`` summed) are evaluated once at the points; a call evaluates the ``f_k`` at one time and
    only the non-separable parts that hold time (``sin(w*t)``) at every point again.

    Parameters
    ----------
    sep : Separable
    time : str
        The time coordinate's name.
    values : mapping of str to ndarray
        The points (every coordinate of ``sep`` but time), broadcastable.
    """

    def __init__(self, sep: Separable, time: str, values: Mapping[str, np.ndarray]) -> None:
        steady, timed = [], {}
        for term in sep.terms:
            factors = dict(term.factors)
            f = factors.pop(time, None)
            if f is None:
                steady.append(term)
            else:
                timed.setdefault(f, []).append(SepTerm(term.coef, tuple(factors.items())))
        self.values = dict(values)
        self.time = time
        self.steady = self._at(Separable(tuple(steady)))
        self.timed = [(f, self._at(Separable(tuple(terms)))) for f, terms in timed.items()]
        self.joints = [j for j in sep.joints if time in j.coordinates]
        self.steady = self.steady + self._at(Separable((), tuple(j for j in sep.joints if time not in j.coordinates)))

    def _at(self, sep: Separable) -> np.ndarray:
        return np.asarray(sep.evaluate(**{k: self.values[k] for k in sep.coordinates}), dtype=float)

    def __call__(self, t: float) -> np.ndarray:
        """The coefficient at time ``t`` on the points (broadcast shape of what it depends on)."""
        out = self.steady
        for f, g in self.timed:
            out = out + float(f(t)) * g
        for joint in self.joints:
            values = {**self.values, self.time: np.asarray(float(t))}
            out = out + joint.evaluate(**{k: values[k] for k in joint.coordinates})
        return out
