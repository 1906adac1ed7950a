"""Safe parser from expression text to separated (sum-of-products) form: the public entry.

A PGD solver needs every coefficient of an equation as a sum of products of
one-coordinate functions, ``sum_i c_i prod_j f_ij(x_j)``. This module turns the
text of an expression or equation into that form; a part that is not separable
(``sin(w*t)``, ``1/(1 + a*b)``) is kept as an expression tree of its
coordinates (:class:`Joint`), which the solvers separate numerically on their
nodes (:mod:`pgdcli.discretization.separate`) and the references evaluate directly.

The text never reaches ``eval``/``exec``: it is parsed with
``ast.parse(text, mode="eval")`` and the tree is walked against a whitelist of
node types (:mod:`pgdcli.problem.parser`). Everything else is rejected with the
offending source segment.

Modules
-------
:mod:`~pgdcli.problem.trees`
    Expression trees: the one evaluator, smart constructors, text.
:mod:`~pgdcli.problem.terms`
    :class:`Func1D` (a function of one coordinate, or a constant) and :class:`SepTerm`
    (``coef * prod_j f_j(x_j)``, at most one factor per coordinate).
:mod:`~pgdcli.problem.separable`
    :class:`Joint` (``SepTerm * g(x_a, x_b, ...)``, a function of two or more coordinates
    jointly) and :class:`Separable` (a sum of terms plus non-separable parts).
:mod:`~pgdcli.problem.polynomial`
    :class:`Atom` (an unknown or one of its derivatives), ``Monomial`` (a sorted tuple of
    atoms) and :class:`Polynomial` (``Monomial -> Separable``; the unknown-free part is ``()``).
:mod:`~pgdcli.problem.parser`, :mod:`~pgdcli.problem.algebra`
    The whitelisted walk and the separated algebra of quotients, powers and functions.
This module parses whole expressions and equations and re-exports the names above.
"""

from __future__ import annotations

import ast
import dataclasses
import math
import numbers
import re
from typing import Mapping

from ..errors import ExpressionError
from .parser import MAX_TERMS, ParseOptions, Parser, shorten, where_prefix
from .polynomial import Atom, Monomial, Polynomial, format_monomial, make_monomial
from .separable import Joint, Separable, merge_to_function
from .terms import Func1D, SepTerm
from .trees import FUNCTIONS

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
    "ParseOptions",
    "make_monomial",
    "format_monomial",
    "merge_to_function",
    "parse_expression",
    "parse_equation",
    "evaluate_constant",
]

#: Names with a fixed meaning in expressions (the spec layer reserves them).
BUILTIN_NAMES = frozenset({"der", "pi", *FUNCTIONS})

# longer texts are almost certainly generated or malicious; refuse early
_MAX_TEXT_LENGTH = 10_000


def _normalize_text(text: object, where: str, what: str = "an expression") -> str:
    """Check the type and size of a text; fold whitespace (YAML block scalars keep newlines)."""
    if not isinstance(text, str):
        raise ExpressionError(f"{where_prefix(where)}expected {what} as a string, got {text!r}")
    if len(text) > _MAX_TEXT_LENGTH:
        raise ExpressionError(f"{where_prefix(where)}{what} is longer than {_MAX_TEXT_LENGTH} characters")
    # no string literals are allowed, so folding whitespace cannot change a valid expression
    normalized = " ".join(text.split())
    if not normalized:
        raise ExpressionError(f"{where_prefix(where)}expected {what}, got an empty string")
    return normalized


def _parse_tree(text: str, full_text: str, where: str) -> ast.Expression:
    """``ast.parse`` in eval mode (parsing only, never compiled or executed)."""
    try:
        return ast.parse(text, mode="eval")
    except SyntaxError as exc:
        message = f"{exc.msg} at column {exc.offset}" if exc.offset else exc.msg
        if re.search(r"(?<![=<>!:])=(?!=)", text):
            message = "'=' is only allowed once, in equations"
        raise ExpressionError(f"{where_prefix(where)}invalid expression '{shorten(full_text)}': {message}") from None
    except (ValueError, RecursionError, MemoryError) as exc:
        raise ExpressionError(f"{where_prefix(where)}invalid expression '{shorten(full_text)}': {exc or 'too deeply nested'}") from None


def _parse_side(text: str, full_text: str, options: ParseOptions) -> Polynomial:
    tree = _parse_tree(text, full_text, options.where)
    try:
        return Parser(text, full_text, options).visit(tree.body, None)
    except RecursionError:
        raise ExpressionError(f"{where_prefix(options.where)}expression '{shorten(full_text)}' is too deeply nested") from None


def _options(options: ParseOptions | None, keywords: dict) -> ParseOptions:
    """The options of a parse: given whole, as keywords, or given whole with some replaced."""
    options = ParseOptions(**keywords) if options is None else dataclasses.replace(options, **keywords)
    # the spec layer guarantees unique names; a clash here is a programming error, not a user error
    names = [*options.coordinates, *options.constants, *options.unknowns]
    if len(set(names)) != len(names) or BUILTIN_NAMES.intersection(names):
        raise ValueError(f"names must be unique and not built-in: {names}")
    return options


def parse_expression(text: str, options: ParseOptions | None = None, /, **keywords) -> Polynomial:
    """Parse an expression into a polynomial in the unknowns with separated coefficients.

    Parameters
    ----------
    text : str
        The expression, e.g. ``"-k*u + a*exp(-t)"``.
    options : ParseOptions, optional
        Names, time coordinate, message prefix and what is allowed.
    **keywords
        The fields of :class:`ParseOptions` (``coordinates``, ``constants``, ``unknowns``,
        ``time``, ``where``, ``allow_der``, ``allow_space_derivatives``): all of them without
        ``options``, else those that replace its fields.

    Returns
    -------
    Polynomial

    Raises
    ------
    ExpressionError
        Syntax outside the whitelist, unknown names, non-separable or
        non-polynomial terms, division by zero, overflow.
    """
    options = _options(options, keywords)
    normalized = _normalize_text(text, options.where)
    return _parse_side(normalized, normalized, options)


def parse_equation(text: str, options: ParseOptions | None = None, /, **keywords) -> Polynomial:
    """Parse ``"lhs = rhs"`` into the polynomial ``lhs - rhs`` (which equals 0).

    Parameters are those of :func:`parse_expression`.

    Raises
    ------
    ExpressionError
        If the text has no or several ``=``, uses ``==``, or a side is invalid.
    """
    options = _options(options, keywords)
    where = options.where
    normalized = _normalize_text(text, where, "an equation")
    # a single '=' that is not part of ==, <=, >=, !=
    positions = [m.start() for m in re.finditer(r"(?<![=<>!])=(?!=)", normalized)]
    if len(positions) != 1:
        hint = "; use a single '='" if "==" in normalized else ""
        raise ExpressionError(
            f"{where_prefix(where)}expected an equation 'lhs = rhs' with exactly one '=', got '{shorten(normalized)}'{hint}"
        )
    lhs_text, rhs_text = normalized[: positions[0]].strip(), normalized[positions[0] + 1 :].strip()
    if not lhs_text or not rhs_text:
        raise ExpressionError(f"{where_prefix(where)}equation '{normalized}' has an empty side")
    return _parse_side(lhs_text, normalized, options) - _parse_side(rhs_text, normalized, options)


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
            raise ExpressionError(f"{where_prefix(where)}expected a finite number, got {str(value)[:40]}")
        return number
    if not isinstance(value, str):
        raise ExpressionError(f"{where_prefix(where)}expected a number or an expression string, got {value!r}")
    options = ParseOptions(coordinates=(), constants=constants, unknowns=(), time=None, where=where, allow_der=False)
    poly = parse_expression(value, options)
    # without coordinates and unknowns every valid expression folds to a number
    return float(poly.coefficient(()).constant_value)