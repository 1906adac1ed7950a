"""Safe parser from expression text to separated (sum-of-products) form.

A PGD solver needs every coefficient of an equation as a sum of products of
one-coordinate functions, ``sum_i c_i prod_j f_ij(x_j)``. This module turns the
text of an expression or equation into that form; a part that is not separable
(``sin(w*t)``, ``1/(1 + a*b)``) is kept as an expression tree of its
coordinates (:class:`Joint`), which the solvers separate numerically on their
nodes (:mod:`pgdcli.discretization.separate`) and the references evaluate directly.

The text never reaches ``eval``/``exec``: it is parsed with
``ast.parse(text, mode="eval")`` and the tree is walked against a whitelist of
node types (numbers, ``+ - * / **``, unary signs, names, calls of a few
functions and ``der``). Everything else is rejected with the offending source
segment.

Data model
----------
:class:`Func1D`
    A function of one coordinate (or a constant) as a small expression tree.
:class:`SepTerm`
    ``coef * prod_j f_j(x_j)``, at most one factor per coordinate.
:class:`Joint`
    ``SepTerm * g(x_a, x_b, ...)``: a function of two or more coordinates jointly,
    kept as a tree with named coordinate leaves ``('coord', name)``.
:class:`Separable`
    A sum of :class:`SepTerm` (``terms``) plus non-separable parts (``joints``).
:class:`Atom`, ``Monomial``
    An unknown or one of its derivatives; a sorted tuple of atoms.
:class:`Polynomial`
    ``Monomial -> Separable`` coefficient: the unknown-free part is the
    monomial ``()``.
"""

from __future__ import annotations

import ast
import difflib
import math
import numbers
import re
from dataclasses import dataclass
from types import MappingProxyType
from typing import Callable, Iterable, Iterator, Mapping, NamedTuple, Sequence

import numpy as np

from ..errors import ExpressionError
from .general import FUNCTIONS, GENERAL, build_tree, mentions, render

__all__ = [
    "FUNCTIONS",
    "BUILTIN_NAMES",
    "MAX_TERMS",
    "Func1D",
    "SepTerm",
    "Joint",
    "Separable",
    "Atom",
    "Monomial",
    "Polynomial",
    "make_monomial",
    "format_monomial",
    "merge_to_function",
    "parse_expression",
    "parse_equation",
    "evaluate_constant",
]

#: Names with a fixed meaning in expressions (the spec layer reserves them).
BUILTIN_NAMES = frozenset({"der", "pi", *FUNCTIONS})

#: Most separated terms an expression may expand to (guards ``(k+a+t)**50``).
MAX_TERMS = 10_000
# term products (before like terms combine) over a whole expression: bounds
# the work of one parse to well under a second
_MAX_PRODUCTS = 10 * MAX_TERMS
# largest integer exponent expanded by repeated multiplication
_MAX_POWER = 1_000
# longer texts are almost certainly generated or malicious; refuse early
_MAX_TEXT_LENGTH = 10_000

_BINARY: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "add": np.add,
    "sub": np.subtract,
    "mul": np.multiply,
    "div": np.divide,
    "pow": np.power,
}


# ----------------------------------------------------------------------------------------------
# expression trees of one variable: smart constructors, evaluation, rendering
# ----------------------------------------------------------------------------------------------
_VAR: tuple = ("var",)


def _num(value: float) -> tuple:
    """Leaf node of a number."""
    return ("num", float(value))


def _num_value(tree: tuple) -> float | None:
    """The number of a ``num`` leaf, else None."""
    return tree[1] if tree[0] == "num" else None


def _is_nonneg_int(value: float | None) -> bool:
    return value is not None and value >= 0 and float(value).is_integer()


def _t_neg(a: tuple) -> tuple:
    va = _num_value(a)
    if va is not None:
        return _num(-va)
    if a[0] == "neg":
        return a[1]
    return ("neg", a)


def _t_add(a: tuple, b: tuple) -> tuple:
    va, vb = _num_value(a), _num_value(b)
    if va is not None and vb is not None:
        return _num(va + vb)
    if va == 0:
        return b
    if vb == 0:
        return a
    # "t - 3" reads better than "t + -3"
    if vb is not None and vb < 0:
        return ("sub", a, _num(-vb))
    if b[0] == "neg":
        return ("sub", a, b[1])
    if b[0] == "mul" and (_num_value(b[1]) or 0) < 0:
        return ("sub", a, _t_mul(_num(-b[1][1]), b[2]))
    return ("add", a, b)


def _int_power(tree: tuple) -> tuple[tuple, int | None]:
    """Split ``base**n`` with a non-negative integer n; other trees are ``tree**1``."""
    if tree[0] == "pow" and _is_nonneg_int(_num_value(tree[2])):
        return tree[1], int(tree[2][1])
    if tree[0] == "num":
        return tree, None
    return tree, 1


def _t_mul(a: tuple, b: tuple) -> tuple:
    va, vb = _num_value(a), _num_value(b)
    if va is not None and vb is not None:
        return _num(va * vb)
    for v, other in ((va, b), (vb, a)):
        if v == 1:
            return other
        if v == -1:
            return _t_neg(other)
    # a * (1/b) -> a/b, which reads better and saves an operation
    if b[0] == "div" and _num_value(b[1]) == 1:
        return _t_div(a, b[2])
    if a[0] == "div" and _num_value(a[1]) == 1:
        return _t_div(b, a[2])
    # x**m * x**n -> x**(m+n) only for non-negative integer m, n: exact for every real x
    base_a, n_a = _int_power(a)
    base_b, n_b = _int_power(b)
    if n_a is not None and n_b is not None and base_a == base_b:
        return _t_pow(base_a, _num(n_a + n_b))
    # numbers first, so that 2*t and t*2 build the same tree
    if vb is not None:
        return ("mul", b, a)
    return ("mul", a, b)


def _t_div(a: tuple, b: tuple) -> tuple:
    if _num_value(b) == 1:
        return a
    # x**m / x**n -> x**(m-n) for non-negative integers: k*a/k must not keep a
    # removable singularity at k = 0 (nor cost an extra operation)
    base_a, m = _int_power(a)
    base_b, n = _int_power(b)
    if m is not None and n is not None and base_a == base_b:
        if m >= n:
            return _t_pow(base_a, _num(m - n))
        return ("div", _num(1.0), _t_pow(base_a, _num(n - m)))
    # 1/(1/g) = g, which keeps repeated inversion from nesting
    if _num_value(a) == 1 and b[0] == "div" and _num_value(b[1]) == 1:
        return b[2]
    return ("div", a, b)


def _t_pow(a: tuple, b: tuple) -> tuple:
    vb = _num_value(b)
    if vb == 1:
        return a
    if vb == 0:
        return _num(1.0)
    if vb == -1:
        return _t_div(_num(1.0), a)
    return ("pow", a, b)


def _evaluate_tree(tree: tuple, x) -> np.ndarray:
    """Evaluate a tree at the points x (a float array; for a joint tree, coordinate name -> array)."""
    kind = tree[0]
    if kind == "num":
        return np.full(np.shape(x) if not isinstance(x, Mapping) else (), tree[1])
    if kind == "var":
        return x
    if kind == "coord":
        return np.asarray(x[tree[1]], dtype=float)
    if kind == "call":
        return FUNCTIONS[tree[1]](_evaluate_tree(tree[2], x))
    if kind == "neg":
        return np.negative(_evaluate_tree(tree[1], x))
    return _BINARY[kind](_evaluate_tree(tree[1], x), _evaluate_tree(tree[2], x))


# Python precedences, so that rendered text parses back to the same tree
_PRECEDENCE = {"add": 1, "sub": 1, "mul": 2, "div": 2, "neg": 3, "pow": 4}
_SYMBOL = {"add": " + ", "sub": " - ", "mul": "*", "div": "/", "pow": "**"}
# minimum precedence of (left, right) operands that may go without parentheses
_OPERAND_PRECEDENCE = {"add": (1, 1), "sub": (1, 2), "mul": (2, 2), "div": (2, 3), "pow": (5, 3)}


def _format_number(value: float) -> str:
    """Shortest text of a number: integers without '.0'."""
    if float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(float(value))


def _tree_precedence(tree: tuple) -> int:
    kind = tree[0]
    if kind == "num":
        return 3 if tree[1] < 0 else 5
    if kind in ("var", "call", "coord"):
        return 5
    return _PRECEDENCE[kind]


def _render(tree: tuple, name: str, min_precedence: int = 0) -> str:
    """Text of a tree, in parentheses if it binds less tightly than required."""
    text = _render_bare(tree, name)
    return f"({text})" if _tree_precedence(tree) < min_precedence else text


def _render_bare(tree: tuple, name: str) -> str:
    kind = tree[0]
    if kind == "num":
        return _format_number(tree[1])
    if kind == "var":
        return name
    if kind == "coord":
        return tree[1]
    if kind == "call":
        return f"{tree[1]}({_render(tree[2], name)})"
    if kind == "neg":
        return "-" + _render(tree[1], name, 4)
    left, right = _OPERAND_PRECEDENCE[kind]
    return _render(tree[1], name, left) + _SYMBOL[kind] + _render(tree[2], name, right)


# ----------------------------------------------------------------------------------------------
# Func1D, SepTerm, Separable
# ----------------------------------------------------------------------------------------------
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
        result = _evaluate_tree(self.tree, x)
        # never hand back the caller's own array for the identity function
        return x.copy() if result is x else np.asarray(result, dtype=float)

    def __str__(self) -> str:
        return _render(self.tree, self.coordinate or "?")

    @property
    def is_constant(self) -> bool:
        """True if the tree is a single number."""
        return self.tree[0] == "num"

    def times(self, other: Func1D) -> Func1D:
        """Product with a function of the same coordinate (or a constant)."""
        coordinate = self.coordinate or other.coordinate
        if other.coordinate not in (None, coordinate):
            raise ValueError(f"cannot merge functions of {self.coordinate!r} and {other.coordinate!r}")
        return Func1D(coordinate, _t_mul(self.tree, other.tree))

    def reciprocal(self) -> Func1D:
        """``1/f``."""
        return Func1D(self.coordinate, _t_div(_num(1.0), self.tree))

    def power(self, exponent: float) -> Func1D:
        """``f**exponent``."""
        return Func1D(self.coordinate, _t_pow(self.tree, _num(exponent)))

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
        return _term_text(self, signed=True)


def _term_text(term: SepTerm, signed: bool) -> str:
    """Text of a term; with signed=False the sign of the coefficient is left out."""
    numerators, denominators = [], []
    for name, func in term.factors:
        tree = func.tree
        if tree[0] == "div" and _num_value(tree[1]) == 1:
            denominators.append((tree[2], name))
        else:
            numerators.append(_render(tree, name, 2))
    coef = abs(term.coef)
    if coef != 1 or not numerators:
        numerators.insert(0, _format_number(coef))
    text = "*".join(numerators)
    if len(denominators) == 1:
        text += "/" + _render(*denominators[0], 3)
    elif denominators:
        text += "/(" + "*".join(_render(tree, name, 2) for tree, name in denominators) + ")"
    return "-" + text if signed and term.coef < 0 else text


def _substitute(tree: tuple, coordinate: str) -> tuple:
    """A one-coordinate tree with its variable named: ``('var',)`` -> ``('coord', coordinate)``."""
    if tree[0] == "var":
        return ("coord", coordinate)
    if tree[0] == "num" or tree[0] == "coord":
        return tree
    if tree[0] == "call":
        return ("call", tree[1], _substitute(tree[2], coordinate))
    return (tree[0],) + tuple(_substitute(child, coordinate) for child in tree[1:])


def _fix_coordinate(tree: tuple, coordinate: str, value: float) -> tuple:
    """A joint tree with the leaves of one coordinate replaced by a number (not simplified)."""
    if tree[0] == "coord":
        return _num(value) if tree[1] == coordinate else tree
    if tree[0] in ("num", "var"):
        return tree
    if tree[0] == "call":
        return ("call", tree[1], _fix_coordinate(tree[2], coordinate, value))
    return (tree[0],) + tuple(_fix_coordinate(child, coordinate, value) for child in tree[1:])


def _tree_coordinates(tree: tuple) -> frozenset[str]:
    """Coordinates named in a joint tree."""
    if tree[0] == "coord":
        return frozenset((tree[1],))
    if tree[0] in ("num", "var"):
        return frozenset()
    children = tree[2:] if tree[0] == "call" else tree[1:]
    return frozenset().union(*(_tree_coordinates(child) for child in children))


def _term_tree(term: SepTerm) -> tuple:
    """A separable term as one joint tree (coordinates named)."""
    tree = _num(term.coef)
    for name, func in term.factors:
        tree = _t_mul(tree, _substitute(func.tree, name))
    return tree


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
        inside = _tree_coordinates(tree)
        kept = []
        for name, func in term.factors:
            if name in inside:
                tree = _t_mul(tree, _substitute(func.tree, name))
            else:
                kept.append((name, func))
        return cls(SepTerm(term.coef, tuple(kept)), tree)

    @property
    def tree_coordinates(self) -> frozenset[str]:
        """Coordinates of the joint function (at least two)."""
        return _tree_coordinates(self.tree)

    @property
    def coordinates(self) -> frozenset[str]:
        return self.term.coordinates | self.tree_coordinates

    def evaluate(self, /, **values: np.ndarray) -> np.ndarray:
        """The value with numpy broadcasting; values maps coordinate names to arrays."""
        return self.term.evaluate(**values) * np.asarray(_evaluate_tree(self.tree, values), dtype=float)

    def evaluate_tree(self, values: Mapping[str, np.ndarray]) -> np.ndarray:
        """The joint function alone (without ``term``) at broadcast arrays of its coordinates."""
        return np.asarray(_evaluate_tree(self.tree, values), dtype=float)

    def with_value(self, coordinate: str, value: float) -> Joint:
        """The joint function with one coordinate fixed at a number (the factor ``term`` unchanged)."""
        return Joint(self.term, _fix_coordinate(self.tree, coordinate, value))

    def function_text(self) -> str:
        """Text of the joint function alone, e.g. ``sin(w*t)``."""
        return _render(self.tree, "?")

    def scaled(self, factor: float) -> Joint:
        return Joint(self.term.scaled(factor), self.tree)

    def times_term(self, other: SepTerm) -> Joint:
        return Joint.make(self.term * other, self.tree)

    def __mul__(self, other: Joint) -> Joint:
        if not isinstance(other, Joint):
            return NotImplemented
        return Joint.make(self.term * other.term, _t_mul(self.tree, other.tree))

    def __str__(self) -> str:
        text = _term_text(SepTerm(abs(self.term.coef), self.term.factors), signed=False)
        inner = _render(self.tree, "?", 2)
        text = inner if text == "1" else f"{text}*{inner}"
        return "-" + text if self.term.coef < 0 else text


def _normalize_joints(joints: Iterable[Joint]) -> tuple[Joint, ...]:
    """Combine joints with equal factors and trees, drop zero ones (first-appearance order)."""
    coefs: dict[tuple, float] = {}
    for joint in joints:
        key = (joint.term.factors, joint.tree)
        coefs[key] = coefs.get(key, 0.0) + joint.term.coef
    return tuple(Joint(SepTerm(coef, factors), tree) for (factors, tree), coef in coefs.items() if coef != 0)


def _join_signed(pieces: Iterable[tuple[bool, str]]) -> str:
    """Join (negative, text) pieces as 'a + b - c'."""
    out = ""
    for negative, text in pieces:
        if not out:
            out = "-" + text if negative else text
        else:
            out += (" - " if negative else " + ") + text
    return out or "0"


def _normalize_terms(terms: Iterable[SepTerm]) -> tuple[SepTerm, ...]:
    """Combine terms with equal factors and drop zero terms (first-appearance order)."""
    coefs: dict[tuple, float] = {}
    for term in terms:
        coefs[term.factors] = coefs.get(term.factors, 0.0) + term.coef
    return tuple(SepTerm(coef, factors) for factors, coef in coefs.items() if coef != 0)


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
        object.__setattr__(self, "terms", _normalize_terms(self.terms))
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
            return cls.constant(_constant_tree_value(func.tree))
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
        other = _as_separable(other)
        if other is None:
            return NotImplemented
        return Separable(self.terms + other.terms, self.joints + other.joints)

    __radd__ = __add__

    def __neg__(self) -> Separable:
        return self * -1.0

    def __sub__(self, other: Separable | float) -> Separable:
        other = _as_separable(other)
        if other is None:
            return NotImplemented
        return self + (-other)

    def __rsub__(self, other: float) -> Separable:
        other = _as_separable(other)
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
        pieces = [(term.coef < 0, _term_text(term, signed=False)) for term in self.terms]
        pieces += [(j.term.coef < 0, str(j.scaled(-1.0) if j.term.coef < 0 else j)) for j in self.joints]
        return _join_signed(pieces)

    def tree(self) -> tuple:
        """The whole sum as one expression tree with named coordinates (leaves ``('coord', name)``)."""
        tree = _num(0.0)
        for term in self.terms:
            tree = _t_add(tree, _term_tree(term))
        for joint in self.joints:
            tree = _t_add(tree, _t_mul(_term_tree(joint.term), joint.tree))
        return tree


def _as_separable(value: object) -> Separable | None:
    if isinstance(value, Separable):
        return value
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return Separable.constant(float(value))
    return None


def _constant_tree_value(tree: tuple) -> float:
    """Value of a tree without variable (evaluated once, at a dummy point)."""
    return float(_evaluate_tree(tree, np.zeros(())))


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
    tree = _num(0.0)
    for term in sep.terms:
        piece = _num(term.coef)
        for _, func in term.factors:
            piece = _t_mul(piece, func.tree)
        tree = _t_add(tree, piece)
    return Func1D(coordinate, tree)


# ----------------------------------------------------------------------------------------------
# Atom, Monomial, Polynomial
# ----------------------------------------------------------------------------------------------
class Atom(NamedTuple):
    """An unknown or one of its derivatives.

    Attributes
    ----------
    unknown : str
    coordinate : str or None
        None for the value itself, else the coordinate of the derivative (the
        time coordinate for ``der(u)``).
    order : int
        0 for the value, 1 or 2 for derivatives.
    """

    unknown: str
    coordinate: str | None = None
    order: int = 0

    def text(self, time: str | None = None) -> str:
        """Text as written in an equation; ``der(u)`` if the coordinate is ``time``."""
        if self.order == 0:
            return self.unknown
        if self.order == 1 and self.coordinate == time:
            return f"der({self.unknown})"
        if self.order == 1:
            return f"der({self.unknown}, {self.coordinate})"
        return f"der({self.unknown}, {self.coordinate}, {self.order})"

    def __str__(self) -> str:
        return self.text()


#: Sorted tuple of atoms; ``()`` is the unknown-free part.
Monomial = tuple  # tuple[Atom, ...]


def _atom_key(atom: Atom) -> tuple:
    # None and str do not compare: the value itself sorts before its derivatives
    return (atom.unknown, atom.coordinate or "", atom.order)


def make_monomial(*atoms: Atom) -> Monomial:
    """The canonical (sorted) monomial of some atoms."""
    return tuple(sorted(atoms, key=_atom_key))


def format_monomial(monomial: Monomial, time: str | None = None) -> str:
    """Text of a monomial, e.g. ``u*v``, ``der(u)*u``, ``u**2``; '1' for ``()``."""
    counts: dict[Atom, int] = {}
    for atom in monomial:
        counts[atom] = counts.get(atom, 0) + 1
    parts = [atom.text(time) + (f"**{n}" if n > 1 else "") for atom, n in counts.items()]
    return "*".join(parts) or "1"


def _monomial_sort_key(monomial: Monomial) -> tuple:
    return (len(monomial), [_atom_key(atom) for atom in monomial])


@dataclass(frozen=True, eq=False)
class Polynomial:
    """A polynomial in unknowns (and their derivatives) with separated coefficients.

    Attributes
    ----------
    terms : Mapping[Monomial, Separable]
        Read-only mapping without zero coefficients, ordered by degree.
        ``terms[()]`` is the unknown-free part, ``terms[(Atom('u'),)]`` the
        coefficient of u, ``terms[(Atom('u', 't', 1),)]`` that of der(u).
    """

    terms: Mapping[Monomial, Separable]

    def __post_init__(self) -> None:
        merged: dict[Monomial, Separable] = {}
        for monomial, sep in dict(self.terms).items():
            key = make_monomial(*monomial)
            merged[key] = merged[key] + sep if key in merged else sep
        ordered = {m: merged[m] for m in sorted(merged, key=_monomial_sort_key) if not merged[m].is_zero}
        object.__setattr__(self, "terms", MappingProxyType(ordered))

    # -- constructors ----------------------------------------------------------------------
    @classmethod
    def constant(cls, value: float) -> Polynomial:
        return cls({(): Separable.constant(value)})

    @classmethod
    def from_separable(cls, sep: Separable) -> Polynomial:
        return cls({(): sep})

    @classmethod
    def atom(cls, atom: Atom) -> Polynomial:
        return cls({(atom,): Separable.constant(1.0)})

    # -- mapping interface -----------------------------------------------------------------
    def items(self):
        return self.terms.items()

    def keys(self):
        return self.terms.keys()

    def values(self):
        return self.terms.values()

    def get(self, monomial: Monomial, default: Separable | None = None) -> Separable | None:
        return self.terms.get(monomial, default)

    def __getitem__(self, monomial: Monomial) -> Separable:
        return self.terms[monomial]

    def __contains__(self, monomial: object) -> bool:
        return monomial in self.terms

    def __iter__(self) -> Iterator[Monomial]:
        return iter(self.terms)

    def coefficient(self, monomial: Monomial = ()) -> Separable:
        """Coefficient of a monomial, zero if absent (``()``: the unknown-free part)."""
        return self.terms.get(make_monomial(*monomial), Separable())

    # -- properties ------------------------------------------------------------------------
    @property
    def degree(self) -> int:
        """Largest number of atoms in a monomial (0 for an unknown-free polynomial)."""
        return max((len(m) for m in self.terms), default=0)

    @property
    def atoms(self) -> frozenset[Atom]:
        return frozenset(atom for monomial in self.terms for atom in monomial)

    @property
    def unknowns(self) -> frozenset[str]:
        return frozenset(atom.unknown for atom in self.atoms)

    @property
    def is_zero(self) -> bool:
        return not self.terms

    @property
    def term_count(self) -> int:
        """Total number of separated terms over all coefficients."""
        return sum(len(sep.terms) + len(sep.joints) for sep in self.terms.values())

    # -- arithmetic ------------------------------------------------------------------------
    def __add__(self, other: Polynomial | Separable | float) -> Polynomial:
        other = _as_polynomial(other)
        if other is None:
            return NotImplemented
        merged = dict(self.terms)
        for monomial, sep in other.items():
            merged[monomial] = merged[monomial] + sep if monomial in merged else sep
        return Polynomial(merged)

    __radd__ = __add__

    def __neg__(self) -> Polynomial:
        return Polynomial({m: -sep for m, sep in self.items()})

    def __sub__(self, other: Polynomial | Separable | float) -> Polynomial:
        other = _as_polynomial(other)
        if other is None:
            return NotImplemented
        return self + (-other)

    def __rsub__(self, other: Separable | float) -> Polynomial:
        other = _as_polynomial(other)
        if other is None:
            return NotImplemented
        return other + (-self)

    def __mul__(self, other: Polynomial | Separable | float) -> Polynomial:
        other = _as_polynomial(other)
        if other is None:
            return NotImplemented
        product: dict[Monomial, Separable] = {}
        for m1, s1 in self.items():
            for m2, s2 in other.items():
                key = make_monomial(*m1, *m2)
                sep = s1 * s2
                product[key] = product[key] + sep if key in product else sep
        return Polynomial(product)

    __rmul__ = __mul__

    # -- comparison, text ------------------------------------------------------------------
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Polynomial):
            return NotImplemented
        return dict(self.terms) == dict(other.terms)

    def __hash__(self) -> int:
        return hash(frozenset(self.terms.items()))

    def __repr__(self) -> str:
        return f"Polynomial({dict(self.terms)!r})"

    def __str__(self) -> str:
        pieces: list[tuple[bool, str]] = []
        for monomial, sep in self.items():
            if not monomial:
                pieces += [(t.coef < 0, _term_text(t, signed=False)) for t in sep.terms]
                pieces += [(j.term.coef < 0, str(j.scaled(-1.0) if j.term.coef < 0 else j)) for j in sep.joints]
            elif len(sep.terms) == 1 and not sep.joints:
                term = sep.terms[0]
                coef_text = _term_text(term, signed=False)
                text = format_monomial(monomial) if coef_text == "1" else f"{coef_text}*{format_monomial(monomial)}"
                pieces.append((term.coef < 0, text))
            else:
                pieces.append((False, f"({sep})*{format_monomial(monomial)}"))
        return _join_signed(pieces)


def _as_polynomial(value: object) -> Polynomial | None:
    if isinstance(value, Polynomial):
        return value
    sep = _as_separable(value)
    return None if sep is None else Polynomial.from_separable(sep)


# ----------------------------------------------------------------------------------------------
# the parser: whitelisted AST walk
# ----------------------------------------------------------------------------------------------
# where an unknown or der() was found, for messages: (phrase, node of the enclosing construct)
_CONTEXT_PHRASES = {
    "argument": "inside the function argument of",
    "denominator": "in the denominator of",
    "exponent": "in the exponent of",
}

_DISALLOWED_KINDS = {
    ast.Attribute: "attribute access",
    ast.Subscript: "subscript",
    ast.Lambda: "lambda",
    ast.Compare: "comparison",
    ast.BoolOp: "boolean operator",
    ast.IfExp: "conditional expression",
    ast.NamedExpr: "assignment expression",
    ast.JoinedStr: "f-string",
    ast.Starred: "starred argument",
    ast.Tuple: "tuple",
    ast.List: "list",
    ast.Dict: "dict",
    ast.Set: "set",
}


_OPERATOR_SYMBOLS = {
    ast.BitXor: "^",
    ast.FloorDiv: "//",
    ast.Mod: "%",
    ast.MatMult: "@",
    ast.LShift: "<<",
    ast.RShift: ">>",
    ast.BitOr: "|",
    ast.BitAnd: "&",
    ast.Not: "not",
    ast.Invert: "~",
}


def _joint_of(tree: tuple) -> Separable:
    """A non-separable function of coordinates (a tree with named coordinates) as a Separable."""
    if len(_tree_coordinates(tree)) < 2:  # cannot happen for the parser's callers: kept as a guard
        raise ValueError(f"a joint function needs two or more coordinates: {tree}")
    return Separable((), (Joint(SepTerm(1.0), tree),))


@dataclass(frozen=True)
class _Context:
    """The construct an operand sits in, where unknowns and der() are not allowed."""

    kind: str  # a key of _CONTEXT_PHRASES
    node: ast.AST


class _Parser:
    """Walks a whitelisted AST into a :class:`Polynomial`; one instance per text."""

    def __init__(
        self,
        text: str,
        *,
        full_text: str,
        where: str,
        coordinates: Sequence[str],
        constants: Mapping[str, float],
        unknowns: Sequence[str],
        time: str | None,
        allow_der: bool,
        allow_space_derivatives: bool,
    ) -> None:
        self.text = text
        self.full_text = full_text
        self.where = where
        self.coordinates = tuple(coordinates)
        self.constants = dict(constants)
        self.unknowns = tuple(unknowns)
        self.time = time
        self.allow_der = allow_der
        self.allow_space_derivatives = allow_space_derivatives
        self.products = 0  # term products so far: bounds the work of one parse

    # -- messages --------------------------------------------------------------------------
    def error(self, message: str) -> ExpressionError:
        return ExpressionError(_prefix(self.where) + message)

    def segment(self, node: ast.AST) -> str:
        return _shorten(ast.get_source_segment(self.text, node) or ast.unparse(node))

    def quote(self, node: ast.AST) -> str:
        """``'segment'``, followed by ``in 'full text'`` when that adds context."""
        segment = self.segment(node)
        full = _shorten(self.full_text)
        return f"'{segment}'" if segment == full else f"'{segment}' in '{full}'"

    def allowed(self) -> str:
        der = ", and der(u) for the time derivative of an unknown u" if self.allow_der else ""
        return (
            "allowed are numbers, + - * / **, parentheses, names of coordinates, constants"
            f" and unknowns, pi, the functions {', '.join(FUNCTIONS)}{der}"
        )

    def disallowed(self, node: ast.AST, what: str | None = None) -> ExpressionError:
        what = what or _DISALLOWED_KINDS.get(type(node), f"{type(node).__name__} syntax")
        return self.error(f"{what} {self.quote(node)} is not allowed; {self.allowed()}")

    # -- dispatch --------------------------------------------------------------------------
    def visit(self, node: ast.AST, context: _Context | None) -> Polynomial:
        if isinstance(node, ast.Constant):
            return self.visit_constant(node)
        if isinstance(node, ast.Name):
            return self.visit_name(node, context)
        if isinstance(node, ast.UnaryOp):
            return self.visit_unary(node, context)
        if isinstance(node, ast.BinOp):
            result = self.visit_binary(node, context)
        elif isinstance(node, ast.Call):
            result = self.visit_call(node, context)
        else:
            raise self.disallowed(node)
        self.check_finite(result, node)
        return result

    def check_finite(self, result: Polynomial, node: ast.AST) -> None:
        for sep in result.values():
            if not all(math.isfinite(term.coef) for term in (*sep.terms, *(j.term for j in sep.joints))):
                raise self.error(f"{self.quote(node)} overflows: a coefficient is not a finite number")

    def visit_constant(self, node: ast.Constant) -> Polynomial:
        value = node.value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            what = "string" if isinstance(value, str) else f"literal {value!r}"
            raise self.disallowed(node, what)
        try:
            number = float(value)
        except OverflowError:
            number = math.inf
        if not math.isfinite(number):
            raise self.error(f"number {self.quote(node)} is too large")
        return Polynomial.constant(number)

    def visit_name(self, node: ast.Name, context: _Context | None) -> Polynomial:
        name = node.id
        if name in self.coordinates:
            return Polynomial.from_separable(Separable.variable(name))
        if name in self.unknowns:
            if context is not None:
                raise self.unknown_in_context(name, context)
            return Polynomial.atom(Atom(name))
        if name in self.constants:
            return Polynomial.constant(self.constants[name])
        if name == "pi":
            return Polynomial.constant(math.pi)
        if name in FUNCTIONS:
            raise self.error(f"function '{name}' in '{_shorten(self.full_text)}' must be called, e.g. {name}(x)")
        if name == "der":
            raise self.error(f"'der' in '{_shorten(self.full_text)}' must be called as der(u) with an unknown u")
        raise self.error(self.unknown_name_message(name, node))

    def unknown_name_message(self, name: str, node: ast.AST) -> str:
        kinds = (("coordinates", self.coordinates), ("constants", tuple(self.constants)), ("unknowns", self.unknowns))
        listing = "".join(f"{kind}: {', '.join(names)}; " for kind, names in kinds if names)
        close = difflib.get_close_matches(name, [*self.coordinates, *self.constants, *self.unknowns, "pi"], n=1)
        hint = f"; did you mean '{close[0]}'?" if close else ""
        return f"unknown name {self.quote(node)} (known names: {listing}pi){hint}"

    def unknown_in_context(self, name: str, context: _Context) -> ExpressionError:
        where = f"{_CONTEXT_PHRASES[context.kind]} {self.quote(context.node)}"
        why = {
            "argument": "functions of unknowns are not supported (equations must be polynomial in the unknowns)",
            "denominator": "division by an unknown is not supported",
            "exponent": "an exponent may not depend on unknowns",
        }[context.kind]
        return self.error(f"unknown '{name}' {where}: {why}")

    # -- operators -------------------------------------------------------------------------
    def visit_unary(self, node: ast.UnaryOp, context: _Context | None) -> Polynomial:
        if isinstance(node.op, ast.USub):
            return -self.visit(node.operand, context)
        if isinstance(node.op, ast.UAdd):
            return self.visit(node.operand, context)
        raise self.disallowed_operator(node)

    def disallowed_operator(self, node: ast.BinOp | ast.UnaryOp) -> ExpressionError:
        symbol = _OPERATOR_SYMBOLS.get(type(node.op), type(node.op).__name__)
        hint = "; use ** for powers" if symbol == "^" else f"; {self.allowed()}"
        return self.error(f"operator '{symbol}' in {self.quote(node)} is not allowed{hint}")

    def visit_binary(self, node: ast.BinOp, context: _Context | None) -> Polynomial:
        op = node.op
        if not isinstance(op, (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow)):
            raise self.disallowed_operator(node)
        left = self.visit(node.left, context)
        if isinstance(op, ast.Add):
            return left + self.visit(node.right, context)
        if isinstance(op, ast.Sub):
            return left - self.visit(node.right, context)
        if isinstance(op, ast.Mult):
            return self.multiply(left, self.visit(node.right, context), node)
        if isinstance(op, ast.Div):
            if context is None and mentions(node.right, self.unknowns):  # 1/(1 + u): a general atom 1/(...)
                inverse = ast.BinOp(ast.Constant(1), ast.Div(), node.right)
                return self.multiply(left, self.general(node, inverse), node)
            return self.divide(left, self.visit(node.right, _Context("denominator", node)), node)
        if context is None and mentions(node.right, self.unknowns):  # 2**u
            return self.general(node)
        return self.power(left, self.visit(node.right, _Context("exponent", node)), node)

    def general(self, node: ast.AST, term: ast.AST | None = None) -> Polynomial:
        """``term`` (default: ``node``, the text quoted in errors), in which unknowns enter
        non-polynomially, as one general atom (:mod:`pgdcli.problem.general`)."""
        tree = build_tree(node if term is None else term, _GeneralNames(self, node))
        return Polynomial.atom(Atom(render(tree), GENERAL, 0))

    def multiply(self, a: Polynomial, b: Polynomial, node: ast.AST) -> Polynomial:
        """``a*b``, refusing expansions that would blow up the number of terms or the work."""
        products = sum(len(s1.terms) * len(s2.terms) for s1 in a.values() for s2 in b.values())
        self.products += products
        if self.products > _MAX_PRODUCTS:
            raise self.too_many_terms(node)
        result = a * b
        if result.term_count > MAX_TERMS:
            raise self.too_many_terms(node)
        return result

    def too_many_terms(self, node: ast.AST) -> ExpressionError:
        return self.error(f"expanding {self.quote(node)} gives too many separated terms (at most {MAX_TERMS})")

    def divide(self, numerator: Polynomial, denominator: Polynomial, node: ast.BinOp) -> Polynomial:
        # the denominator context already rejected unknowns, so only () remains
        den = denominator.coefficient(())
        if den.constant_value == 0:
            raise self.error(f"division by zero in {self.quote(node)}")
        inverse = self.reciprocal(den, node)
        result = self.multiply(numerator, Polynomial.from_separable(inverse), node)
        return self.merge_quotients(numerator, den, result)

    def merge_quotients(self, numerator: Polynomial, den: Separable, product: Polynomial) -> Polynomial:
        """Turn ``(f1(k) + f2(k))/g(k)`` into one term ``(f1 + f2)/g`` instead of one per summand.

        Fewer separated terms make the solver cheaper; coefficients that do not
        depend on the denominator's coordinate alone keep the expanded form.
        """
        den_func = merge_to_function(den)
        if den_func is None or den_func.coordinate is None:
            return product
        merged = dict(product.terms)
        for monomial, sep in numerator.items():
            func = merge_to_function(sep)
            if func is not None and func.coordinate == den_func.coordinate and len(sep.terms) > 1:
                merged[monomial] = Separable.of_function(Func1D(func.coordinate, _t_div(func.tree, den_func.tree)))
        return Polynomial(merged)

    def reciprocal(self, den: Separable, node: ast.BinOp) -> Separable:
        """``1/den`` in separated form, or as a non-separable part (a joint) when it is not separable."""
        if len(den.terms) == 1 and not den.joints:
            term = den.terms[0]
            # 1/(c*f(k)*g(a)) = (1/c) * (1/f(k)) * (1/g(a))
            return Separable((SepTerm(1.0 / term.coef, tuple((n, f.reciprocal()) for n, f in term.factors)),))
        func = merge_to_function(den)
        if func is not None:
            return Separable.of_function(func.reciprocal())
        return _joint_of(("div", _num(1.0), den.tree()))

    def power(self, base: Polynomial, exponent: Polynomial, node: ast.BinOp) -> Polynomial:
        exp_sep = exponent.coefficient(())
        value = exp_sep.constant_value
        if value is not None:
            return self.constant_power(base, value, node)
        return self.coordinate_power(base, exp_sep, node)

    def constant_power(self, base: Polynomial, b: float, node: ast.BinOp) -> Polynomial:
        """``base**b`` for a number b."""
        if base.atoms:
            if _is_nonneg_int(b):
                return self.expand_power(base, int(b), node)
            if all(atom.order == 0 for atom in base.atoms):  # u**0.5, 1/u**2: a general atom
                return self.general(node)
            raise self.error(
                f"non-polynomial term {self.quote(node)}: unknowns may only be raised to non-negative integer powers"
            )
        sep = base.coefficient(())
        c = sep.constant_value
        if c is not None:
            return Polynomial.constant(self.fold_power(c, b, node))
        if len(sep.terms) == 1 and not sep.joints and (sep.terms[0].coef > 0 or float(b).is_integer()):
            # (c*f(k)*g(a))**b = c**b * f(k)**b * g(a)**b
            term = sep.terms[0]
            coef = self.fold_power(term.coef, b, node)
            factors = tuple((n, f.power(b)) for n, f in term.factors)
            return Polynomial.from_separable(Separable((SepTerm(coef, factors),)))
        func = merge_to_function(sep)
        if func is not None:
            return Polynomial.from_separable(Separable.of_function(func.power(b)))
        if _is_nonneg_int(b):
            return self.expand_power(base, int(b), node)
        return Polynomial.from_separable(_joint_of(("pow", sep.tree(), _num(b))))

    def expand_power(self, base: Polynomial, n: int, node: ast.BinOp) -> Polynomial:
        """``base**n`` by repeated multiplication (polynomial degree grows with n)."""
        if n > _MAX_POWER:
            raise self.error(f"exponent of {self.quote(node)} is too large to expand (at most {_MAX_POWER})")
        result = Polynomial.constant(1.0)
        for _ in range(n):
            result = self.multiply(result, base, node)
        return result

    def coordinate_power(self, base: Polynomial, exponent: Separable, node: ast.BinOp) -> Polynomial:
        """``c**g`` for a positive constant c and an exponent depending on coordinates."""
        if base.atoms and all(atom.order == 0 for atom in base.atoms):  # u**k: a general atom
            return self.general(node)
        if base.atoms:
            raise self.error(
                f"non-polynomial term {self.quote(node)}: unknowns may only be raised to non-negative integer powers"
            )
        c = base.coefficient(()).constant_value
        if c is None:  # f(k)**g(a): a function of both, separated numerically by the solvers
            return Polynomial.from_separable(_joint_of(("pow", base.coefficient(()).tree(), exponent.tree())))
        if c <= 0:
            raise self.error(
                f"{self.quote(node)}: a base raised to a coordinate-dependent power must be positive, got {_format_number(c)}"
            )
        return self.exponential(exponent, node, base=c)

    def fold_power(self, a: float, b: float, node: ast.AST) -> float:
        """``a**b`` of numbers, with errors instead of complex, infinite or raised results."""
        try:
            value = a**b
        except ZeroDivisionError:
            raise self.error(f"division by zero in {self.quote(node)}") from None
        except OverflowError:
            raise self.error(f"{self.quote(node)} overflows") from None
        if isinstance(value, complex):
            raise self.error(f"{self.quote(node)} is not a real number (negative base, non-integer exponent)")
        if not math.isfinite(value):
            raise self.error(f"{self.quote(node)} overflows")
        return float(value)

    # -- calls -----------------------------------------------------------------------------
    def visit_call(self, node: ast.Call, context: _Context | None) -> Polynomial:
        if not isinstance(node.func, ast.Name):
            raise self.disallowed(node, "call")
        name = node.func.id
        if name == "der":
            return self.visit_der(node, context)
        if name not in FUNCTIONS:
            raise self.disallowed(node, "call")
        if node.keywords or len(node.args) != 1:
            raise self.error(f"{self.quote(node)}: {name}() takes exactly one argument")
        if context is None and mentions(node.args[0], self.unknowns):
            return self.general(node)  # sin(th): a function of unknowns
        argument = self.visit(node.args[0], _Context("argument", node))
        return Polynomial.from_separable(self.apply_function(name, argument.coefficient(()), node))

    def apply_function(self, name: str, arg: Separable, node: ast.Call) -> Separable:
        """``name(arg)`` for an unknown-free argument, in separated form."""
        value = arg.constant_value
        if value is not None:
            return Separable.constant(self.fold_call(name, value, node))
        func = merge_to_function(arg)
        if func is not None:
            return Separable.of_function(func.apply(name))
        if name == "exp":
            # exp(f(k) + g(a) + h(w, t)) = exp(f(k)) * exp(g(a)) * exp(h(w, t))
            return self.exponential(arg, node).coefficient(())
        if name == "abs" and len(arg.terms) == 1 and not arg.joints:
            # |c f(k) g(a)| = |c| |f(k)| |g(a)|
            term = arg.terms[0]
            return Separable((SepTerm(abs(term.coef), tuple((n, f.apply("abs")) for n, f in term.factors)),))
        # a function of two or more coordinates jointly (sin(w*t)): kept as a tree, separated by the solvers
        return _joint_of(("call", name, arg.tree()))

    def fold_call(self, name: str, value: float, node: ast.AST) -> float:
        with np.errstate(all="ignore"):
            result = float(FUNCTIONS[name](np.float64(value)))
        if not math.isfinite(result):
            raise self.error(f"{self.quote(node)} is not a finite real number")
        return result

    def exponential(self, arg: Separable, node: ast.AST, base: float | None = None) -> Polynomial:
        """``exp(arg)`` (or ``base**arg``) as one product, grouping the terms by coordinate.

        Terms of two or more coordinates (and non-separable parts) go into one joint
        factor ``exp(rest)``, so ``exp(-k - a*t)`` is ``exp(-k)`` times a function of (a, t) only.
        """
        log_base = 1.0 if base is None else math.log(base)
        single = tuple(term for term in arg.terms if len(term.factors) <= 1)
        rest = Separable(tuple(term for term in arg.terms if len(term.factors) > 1), arg.joints)
        if not rest.is_zero:
            scaled = rest.tree() if base is None else _t_mul(_num(log_base), rest.tree())
            joint = _joint_of(("call", "exp", scaled))
            return Polynomial.from_separable(self.exponential(Separable(single), node, base).coefficient(()) * joint)
        groups: dict[str | None, list[SepTerm]] = {}
        for term in single:
            key = term.factors[0][0] if term.factors else None
            groups.setdefault(key, []).append(term)
        coef = 1.0
        factors = []
        for coordinate, terms in groups.items():
            func = merge_to_function(Separable(tuple(terms)))
            if coordinate is None:
                coef = self.fold_call("exp", log_base * _constant_tree_value(func.tree), node)
            elif base is None:
                factors.append((coordinate, func.apply("exp")))
            else:
                factors.append((coordinate, Func1D(coordinate, _t_pow(_num(base), func.tree))))
        return Polynomial.from_separable(Separable((SepTerm(coef, tuple(factors)),)))

    def visit_der(self, node: ast.Call, context: _Context | None) -> Polynomial:
        if not self.allow_der:
            raise self.error(f"der() is not allowed here: {self.quote(node)} (no derivatives in initial values or constants)")
        if context is not None:
            raise self.error(f"der() may not appear {_CONTEXT_PHRASES[context.kind]} {self.quote(context.node)}")
        args = node.args
        if node.keywords or not 1 <= len(args) <= 3:
            raise self.error(f"{self.quote(node)}: expected der(u), der(u, x) or der(u, x, order)")
        target = args[0]
        if not isinstance(target, ast.Name) or target.id not in self.unknowns:
            listing = ", ".join(self.unknowns) or "none"
            raise self.error(
                f"der() may only wrap the name of an unknown, got {self.quote(target)} (unknowns: {listing})"
            )
        coordinate = self.der_coordinate(args[1], node) if len(args) >= 2 else self.time
        order = self.der_order(args[2], node) if len(args) == 3 else 1
        if coordinate is None:
            raise self.error(f"{self.quote(node)}: there is no time coordinate to differentiate by (name one 't' or "
                             "add 'time: <name>'; a steady problem has no der(u))")
        if coordinate != self.time and not self.allow_space_derivatives:
            raise self.error(
                f"{self.quote(node)}: derivatives in non-time coordinates are not supported (only der(u) = du/d{self.time})"
            )
        return Polynomial.atom(Atom(target.id, coordinate, order))

    def der_coordinate(self, node: ast.AST, der_node: ast.Call) -> str:
        if not isinstance(node, ast.Name) or node.id not in self.coordinates:
            raise self.error(
                f"{self.quote(der_node)}: the second argument of der() must be a coordinate"
                f" ({', '.join(self.coordinates)}), got '{self.segment(node)}'"
            )
        return node.id

    def der_order(self, node: ast.AST, der_node: ast.Call) -> int:
        value = node.value if isinstance(node, ast.Constant) else None
        if isinstance(value, bool) or value not in (1, 2) or not isinstance(value, int):
            raise self.error(
                f"{self.quote(der_node)}: the order of a derivative must be 1 or 2, got '{self.segment(node)}'"
            )
        return value


class _GeneralNames:
    """Name resolution and errors of :func:`pgdcli.problem.general.build_tree` for one general term of a parse."""

    def __init__(self, parser: _Parser, term: ast.AST) -> None:
        self.parser, self.term = parser, term

    def resolve(self, node: ast.Name) -> tuple:
        parser, name = self.parser, node.id
        if name in parser.coordinates or name in parser.unknowns:
            return ("name", name)
        if name in parser.constants:
            return ("num", float(parser.constants[name]))
        if name == "pi":
            return ("num", math.pi)
        return parser.visit_name(node, None)  # raises the parser's own message (functions, der, unknown names)

    def refuse(self, node: ast.AST, what: str | None = None) -> ExpressionError:
        parser = self.parser
        if isinstance(node, ast.Constant):
            parser.visit_constant(node)  # raises its message (a string, a number too large)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "der":
            return parser.error(f"der() may not appear inside the non-polynomial term {parser.quote(self.term)}")
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS:
            return parser.error(f"{parser.quote(node)}: {node.func.id}() takes exactly one argument")
        if isinstance(node, (ast.BinOp, ast.UnaryOp)):
            return parser.disallowed_operator(node)
        return parser.disallowed(node, "call" if isinstance(node, ast.Call) else None)


# ----------------------------------------------------------------------------------------------
# public functions
# ----------------------------------------------------------------------------------------------
def _prefix(where: str) -> str:
    return f"{where}: " if where else ""


def _shorten(text: str, limit: int = 120) -> str:
    """Text for a one-line message: long expressions are cut in the middle."""
    if len(text) <= limit:
        return text
    half = (limit - 5) // 2
    return f"{text[:half]} ... {text[-half:]}"


def _normalize_text(text: object, where: str, what: str = "an expression") -> str:
    """Check the type and size of a text; fold whitespace (YAML block scalars keep newlines)."""
    if not isinstance(text, str):
        raise ExpressionError(f"{_prefix(where)}expected {what} as a string, got {text!r}")
    if len(text) > _MAX_TEXT_LENGTH:
        raise ExpressionError(f"{_prefix(where)}{what} is longer than {_MAX_TEXT_LENGTH} characters")
    # no string literals are allowed, so folding whitespace cannot change a valid expression
    normalized = " ".join(text.split())
    if not normalized:
        raise ExpressionError(f"{_prefix(where)}expected {what}, got an empty string")
    return normalized


def _parse_tree(text: str, full_text: str, where: str) -> ast.Expression:
    """``ast.parse`` in eval mode (parsing only, never compiled or executed)."""
    try:
        return ast.parse(text, mode="eval")
    except SyntaxError as exc:
        message = f"{exc.msg} at column {exc.offset}" if exc.offset else exc.msg
        if re.search(r"(?<![=<>!:])=(?!=)", text):
            message = "'=' is only allowed once, in equations"
        raise ExpressionError(f"{_prefix(where)}invalid expression '{_shorten(full_text)}': {message}") from None
    except (ValueError, RecursionError, MemoryError) as exc:
        raise ExpressionError(f"{_prefix(where)}invalid expression '{_shorten(full_text)}': {exc or 'too deeply nested'}") from None


def _parse_side(text: str, full_text: str, where: str, **options) -> Polynomial:
    tree = _parse_tree(text, full_text, where)
    parser = _Parser(text, full_text=full_text, where=where, **options)
    try:
        return parser.visit(tree.body, None)
    except RecursionError:
        raise ExpressionError(f"{_prefix(where)}expression '{_shorten(full_text)}' is too deeply nested") from None


def _check_names(coordinates: Sequence[str], constants: Mapping[str, float], unknowns: Sequence[str]) -> None:
    # the spec layer guarantees this; a clash here is a programming error, not a user error
    names = [*coordinates, *constants, *unknowns]
    if len(set(names)) != len(names) or BUILTIN_NAMES.intersection(names):
        raise ValueError(f"names must be unique and not built-in: {names}")


def parse_expression(
    text: str,
    *,
    coordinates: Sequence[str],
    constants: Mapping[str, float],
    unknowns: Sequence[str],
    time: str | None,
    where: str,
    allow_der: bool = True,
    allow_space_derivatives: bool = False,
) -> Polynomial:
    """Parse an expression into a polynomial in the unknowns with separated coefficients.

    Parameters
    ----------
    text : str
        The expression, e.g. ``"-k*u + a*exp(-t)"``.
    coordinates, unknowns : sequence of str
        Names of coordinates and unknowns.
    constants : mapping of str to float
        Named numbers, substituted by value.
    time : str or None
        The time coordinate: ``der(u)`` is the derivative of u with respect to it.
    where : str
        Context prefix of every error message, e.g. ``"x.yaml: equations[1]"``.
    allow_der : bool
        If False, ``der()`` is an error (initial values, constants).
    allow_space_derivatives : bool
        If True, ``der(u, x[, n])`` is accepted for a non-time coordinate x.

    Returns
    -------
    Polynomial

    Raises
    ------
    ExpressionError
        Syntax outside the whitelist, unknown names, non-separable or
        non-polynomial terms, division by zero, overflow.
    """
    _check_names(coordinates, constants, unknowns)
    normalized = _normalize_text(text, where)
    return _parse_side(
        normalized,
        normalized,
        where,
        coordinates=coordinates,
        constants=constants,
        unknowns=unknowns,
        time=time,
        allow_der=allow_der,
        allow_space_derivatives=allow_space_derivatives,
    )


def parse_equation(
    text: str,
    *,
    coordinates: Sequence[str],
    constants: Mapping[str, float],
    unknowns: Sequence[str],
    time: str | None,
    where: str,
    allow_der: bool = True,
    allow_space_derivatives: bool = False,
) -> Polynomial:
    """Parse ``"lhs = rhs"`` into the polynomial ``lhs - rhs`` (which equals 0).

    Parameters are those of :func:`parse_expression`.

    Raises
    ------
    ExpressionError
        If the text has no or several ``=``, uses ``==``, or a side is invalid.
    """
    _check_names(coordinates, constants, unknowns)
    normalized = _normalize_text(text, where, "an equation")
    # a single '=' that is not part of ==, <=, >=, !=
    positions = [m.start() for m in re.finditer(r"(?<![=<>!])=(?!=)", normalized)]
    if len(positions) != 1:
        hint = "; use a single '='" if "==" in normalized else ""
        raise ExpressionError(
            f"{_prefix(where)}expected an equation 'lhs = rhs' with exactly one '=', got '{_shorten(normalized)}'{hint}"
        )
    lhs_text, rhs_text = normalized[: positions[0]].strip(), normalized[positions[0] + 1 :].strip()
    if not lhs_text or not rhs_text:
        raise ExpressionError(f"{_prefix(where)}equation '{normalized}' has an empty side")
    options = dict(
        coordinates=coordinates,
        constants=constants,
        unknowns=unknowns,
        time=time,
        allow_der=allow_der,
        allow_space_derivatives=allow_space_derivatives,
    )
    lhs = _parse_side(lhs_text, normalized, where, **options)
    rhs = _parse_side(rhs_text, normalized, where, **options)
    return lhs - rhs


def evaluate_constant(text_or_number: str | float, *, constants: Mapping[str, float], where: str) -> float:
    """Value of a constant given as a number or an expression of numbers, pi and constants.

    Parameters
    ----------
    text_or_number : str or float
        E.g. ``9.81``, ``"1e-8"``, ``"2*pi"``, ``"g/2"``.
    constants : mapping of str to float
        Constants defined so far.
    where : str
        Context prefix of error messages.

    Returns
    -------
    float
        A finite number.
    """
    value = text_or_number
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        try:
            number = float(value)
        except OverflowError:  # an integer beyond float's range (YAML reads 400 digits as an int)
            number = math.inf
        if not math.isfinite(number):
            raise ExpressionError(f"{_prefix(where)}expected a finite number, got {str(value)[:40]}")
        return number
    if not isinstance(value, str):
        raise ExpressionError(f"{_prefix(where)}expected a number or an expression string, got {value!r}")
    poly = parse_expression(value, coordinates=(), constants=constants, unknowns=(), time=None, where=where, allow_der=False)
    # without coordinates and unknowns every valid expression folds to a number
    return float(poly.coefficient(()).constant_value)
