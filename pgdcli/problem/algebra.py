"""The rules of separated algebra the expression parser applies: quotients, powers, functions.

A mixin of :class:`pgdcli.problem.parser.Parser`, apart so that each module reads on its own:
the parser walks the syntax, this module decides the separated form of ``a/b``, ``a**b`` and
``f(a)`` for unknown-free operands (a product of one-coordinate functions where the algebra
allows it, else a non-separable part, :class:`~pgdcli.problem.separable.Joint`). The methods
use the parser's ``error``, ``quote``, ``multiply`` and ``general``.
"""

from __future__ import annotations

import ast
import math

import numpy as np

from .polynomial import Polynomial
from .separable import Separable, constant_tree_value, joint_of, merge_to_function
from .terms import Func1D, SepTerm
from .trees import FUNCTIONS, format_number, is_nonneg_int, num, t_div, t_mul, t_pow

__all__ = ["SeparatedAlgebra", "MAX_POWER", "call_tree"]

#: Largest integer exponent expanded by repeated multiplication.
MAX_POWER = 1_000
#: ``exp`` of a sum is split into factors only while every factor's exponent stays within this bound
#: over the box (a product of a few such factors is finite and not subnormal)...
EXPONENT_LIMIT = 300.0
#: ... and the factors' largest values multiply to at most this many times the whole's largest value:
#: the non-separable factor is separated numerically to a bound relative to its own size, which the
#: other factors then carry (``exp(-(x - s)**2/w)`` expanded has factors up to ``exp(2 x s / w)``).
SPLIT_GAIN = 100.0
#: Points per coordinate (at most) of the grid on which the factors' ranges are found.
RANGE_POINTS = 65
#: Most points of that grid.
RANGE_GRID = 20_000


class SeparatedAlgebra:
    """Quotients, powers and function calls in separated form (a mixin of the parser)."""

    # -- quotients -------------------------------------------------------------------------
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
                merged[monomial] = Separable.of_function(Func1D(func.coordinate, t_div(func.tree, den_func.tree)))
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
        return joint_of(("div", num(1.0), den.tree()))

    def power(self, base: Polynomial, exponent: Polynomial, node: ast.BinOp) -> Polynomial:
        exp_sep = exponent.coefficient(())
        value = exp_sep.constant_value
        if value is not None:
            return self.constant_power(base, value, node)
        return self.coordinate_power(base, exp_sep, node)

    def constant_power(self, base: Polynomial, b: float, node: ast.BinOp) -> Polynomial:
        """``base**b`` for a number b."""
        if base.atoms:
            if is_nonneg_int(b):
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
        if is_nonneg_int(b):
            return self.expand_power(base, int(b), node)
        return Polynomial.from_separable(joint_of(("pow", sep.tree(), num(b))))

    def expand_power(self, base: Polynomial, n: int, node: ast.BinOp) -> Polynomial:
        """``base**n`` by repeated multiplication (polynomial degree grows with n)."""
        if n > MAX_POWER:
            raise self.error(f"exponent of {self.quote(node)} is too large to expand (at most {MAX_POWER})")
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
            return Polynomial.from_separable(joint_of(("pow", base.coefficient(()).tree(), exponent.tree())))
        if c <= 0:
            raise self.error(
                f"{self.quote(node)}: a base raised to a coordinate-dependent power must be positive, got {format_number(c)}"
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


    # -- functions -------------------------------------------------------------------------
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
        return joint_of(("call", name, arg.tree()))

    def apply_multi(self, name: str, args: list, comparison: str | None, node: ast.Call) -> Separable:
        """``name(*args)`` of unknown-free arguments (for ``where``, the condition's two operands first):
        a function of one coordinate when all arguments are, else a non-separable part."""
        if name == "smoothstep" and args[0].constant_value is not None and args[0].constant_value == args[1].constant_value:
            raise self.error(f"{self.quote(node)}: smoothstep(edge0, edge1, x) needs edge0 != edge1 (use step(x - edge0))")
        functions = [merge_to_function(arg) for arg in args]
        coordinates = {f.coordinate for f in functions if f is not None and f.coordinate is not None}
        if all(f is not None for f in functions) and len(coordinates) <= 1:
            tree = call_tree(name, [f.tree for f in functions], comparison)
            if not coordinates:
                with np.errstate(all="ignore"):
                    value = constant_tree_value(tree)
                if not math.isfinite(value):
                    raise self.error(f"{self.quote(node)} is not a finite real number")
                return Separable.constant(value)
            return Separable.of_function(Func1D(coordinates.pop(), tree))
        return joint_of(call_tree(name, [arg.tree() for arg in args], comparison))

    def _unsafe_factors(self, single: tuple, rest: Separable, log_base: float) -> set[str]:
        """The coordinates whose factor of ``exp(single + rest)`` must stay in the joint factor ``exp(rest + ...)``.

        Split, ``exp(f(x) + g(s) + h(x, s))`` is ``exp(f) exp(g) exp(h)``: exact, but each factor
        must stay within :data:`EXPONENT_LIMIT` over the box, and together no larger than
        :data:`SPLIT_GAIN` times the whole (the joint ``exp(h)`` is separated numerically relative
        to its own size). A factor of a coordinate of ``h`` that breaks either goes into the joint;
        ranges are sampled on a grid of the box (the domains from the spec; none known: split).
        """
        coupled = rest.coordinates
        if not coupled or not all(c in self.domains for c in rest.coordinates | {
                t.factors[0][0] for t in single if t.factors}):
            return set()
        groups: dict[str, list] = {}
        for term in single:
            if term.factors and term.factors[0][0] in coupled:
                groups.setdefault(term.factors[0][0], []).append(term)
        names = sorted(coupled)
        per = max(3, min(RANGE_POINTS, int(RANGE_GRID ** (1.0 / len(names)))))
        axes = {c: np.linspace(*self.domains[c], per) for c in names}
        grid = dict(zip(names, np.meshgrid(*[axes[c] for c in names], indexing="ij")))
        with np.errstate(all="ignore"):
            joint = log_base * np.asarray(rest.evaluate(**grid), dtype=float)
            parts = {c: log_base * np.asarray(Separable(tuple(ts)).evaluate(**{c: grid[c]}), dtype=float)
                     for c, ts in groups.items()}
        if not np.all(np.isfinite(joint)) or not all(np.all(np.isfinite(v)) for v in parts.values()):
            return set(groups)
        whole = joint + sum(parts.values(), np.zeros_like(joint))
        gain = float(np.max(joint)) + sum(float(np.max(v)) for v in parts.values()) - float(np.max(whole))
        ranges = [joint] + list(parts.values())
        if gain <= math.log(SPLIT_GAIN) and all(float(np.max(np.abs(r))) <= EXPONENT_LIMIT for r in ranges):
            return set()
        return set(groups)

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
        kept = self._unsafe_factors(single, rest, log_base)
        if kept:  # factors that would leave the range of floats, or carry the joint far above the whole
            single = tuple(t for t in single if not (t.factors and t.factors[0][0] in kept))
            rest = Separable(rest.terms + tuple(t for t in arg.terms if t.factors and len(t.factors) == 1
                                                and t.factors[0][0] in kept), rest.joints)
        if not rest.is_zero:
            scaled = rest.tree() if base is None else t_mul(num(log_base), rest.tree())
            joint = joint_of(("call", "exp", scaled))
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
                coef = self.fold_call("exp", log_base * constant_tree_value(func.tree), node)
            elif base is None:
                factors.append((coordinate, func.apply("exp")))
            else:
                factors.append((coordinate, Func1D(coordinate, t_pow(num(base), func.tree))))
        return Polynomial.from_separable(Separable((SepTerm(coef, tuple(factors)),)))


def call_tree(name: str, children: list, comparison: str | None = None) -> tuple:
    """The tree of ``name(*children)``; for ``where`` the first two children are the operands of
    its condition, compared by ``comparison`` (``lt le gt ge``)."""
    if name == "where":
        return ("call", name, (comparison, children[0], children[1]), *children[2:])
    return ("call", name, *children)
