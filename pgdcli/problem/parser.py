"""The expression parser: a walk of Python's ``ast`` against a whitelist, into a :class:`Polynomial`.

The text never reaches ``eval``/``exec``: it is parsed with ``ast.parse(text, mode="eval")``
and the tree is walked against a whitelist of node types (numbers, ``+ - * / **``, unary signs,
names, calls of a few functions and ``der``), dispatched by node type and operator. Everything
else is refused with the offending source segment. The rules for quotients, powers and function
calls are :class:`~pgdcli.problem.algebra.SeparatedAlgebra`; a term in which unknowns enter
non-polynomially becomes a general atom (:mod:`pgdcli.problem.general`).
"""

from __future__ import annotations

import ast
import difflib
import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

from ..errors import ExpressionError
from .algebra import SeparatedAlgebra
from .general import COMPARE_OPS, GENERAL, build_tree, call_problem, mentions, render
from .polynomial import Atom, Polynomial
from .separable import Separable
from .trees import FUNCTIONS, SIGNATURES, signature

__all__ = ["ParseOptions", "Parser", "GeneralNames", "MAX_TERMS", "MAX_PRODUCTS", "where_prefix", "shorten"]

#: Most separated terms an expression may expand to (guards ``(k+a+t)**50``).
MAX_TERMS = 10_000
#: Term products (before like terms combine) over a whole expression: bounds the work of one
#: parse to well under a second.
MAX_PRODUCTS = 10 * MAX_TERMS


@dataclass(frozen=True)
class ParseOptions:
    """What an expression may name and contain: the context of one parse.

    Attributes
    ----------
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
    domains : mapping of str to (float, float)
        The coordinates' domains, where known: ``exp`` of a sum is split into factors only when
        they stay in range over the box (:meth:`~pgdcli.problem.algebra.SeparatedAlgebra.exponential`).
    """

    coordinates: Sequence[str]
    constants: Mapping[str, float]
    unknowns: Sequence[str]
    time: str | None
    where: str
    allow_der: bool = True
    allow_space_derivatives: bool = False
    domains: Mapping[str, tuple] = field(default_factory=dict)


def where_prefix(where: str) -> str:
    return f"{where}: " if where else ""


def shorten(text: str, limit: int = 120) -> str:
    """Text for a one-line message: long expressions are cut in the middle."""
    if len(text) <= limit:
        return text
    half = (limit - 5) // 2
    return f"{text[:half]} ... {text[-half:]}"


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


@dataclass(frozen=True)
class _Enclosing:
    """The construct an operand sits in, where unknowns and der() are not allowed."""

    kind: str  # a key of _CONTEXT_PHRASES
    node: ast.AST


class Parser(SeparatedAlgebra):
    """Walks a whitelisted AST into a :class:`Polynomial`; one instance per text."""

    def __init__(self, text: str, full_text: str, options: ParseOptions) -> None:
        self.text = text
        self.full_text = full_text
        self.where = options.where
        self.coordinates = tuple(options.coordinates)
        self.constants = dict(options.constants)
        self.unknowns = tuple(options.unknowns)
        self.time = options.time
        self.allow_der = options.allow_der
        self.allow_space_derivatives = options.allow_space_derivatives
        self.domains = dict(options.domains)
        self.products = 0  # term products so far: bounds the work of one parse

    # -- messages --------------------------------------------------------------------------
    def error(self, message: str) -> ExpressionError:
        return ExpressionError(where_prefix(self.where) + message)

    def segment(self, node: ast.AST) -> str:
        return shorten(ast.get_source_segment(self.text, node) or ast.unparse(node))

    def quote(self, node: ast.AST) -> str:
        """``'segment'``, followed by ``in 'full text'`` when that adds context."""
        segment = self.segment(node)
        full = shorten(self.full_text)
        return f"'{segment}'" if segment == full else f"'{segment}' in '{full}'"

    def allowed(self) -> str:
        der = ", and der(u) for the time derivative of an unknown u" if self.allow_der else ""
        functions = ", ".join(signature(name) if name in SIGNATURES else name for name in FUNCTIONS)
        return (
            "allowed are numbers, + - * / **, parentheses, names of coordinates, constants"
            f" and unknowns, pi, the functions {functions} (a condition: one comparison with < <= > >=){der}"
        )

    def disallowed(self, node: ast.AST, what: str | None = None) -> ExpressionError:
        what = what or _DISALLOWED_KINDS.get(type(node), f"{type(node).__name__} syntax")
        return self.error(f"{what} {self.quote(node)} is not allowed; {self.allowed()}")

    # -- dispatch by node type -------------------------------------------------------------
    def visit(self, node: ast.AST, context: _Enclosing | None) -> Polynomial:
        visitor = _VISITORS.get(type(node))
        if visitor is None:
            raise self.disallowed(node)
        result = visitor(self, node, context)
        if type(node) in _CHECKED:  # only operations can overflow
            self.check_finite(result, node)
        return result

    def check_finite(self, result: Polynomial, node: ast.AST) -> None:
        for sep in result.values():
            if not all(math.isfinite(term.coef) for term in (*sep.terms, *(j.term for j in sep.joints))):
                raise self.error(f"{self.quote(node)} overflows: a coefficient is not a finite number")

    # -- leaves ----------------------------------------------------------------------------
    def visit_constant(self, node: ast.Constant, context: _Enclosing | None = None) -> Polynomial:
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

    def visit_name(self, node: ast.Name, context: _Enclosing | None) -> Polynomial:
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
            raise self.error(f"function '{name}' in '{shorten(self.full_text)}' must be called, e.g. {name}(x)")
        if name == "der":
            raise self.error(f"'der' in '{shorten(self.full_text)}' must be called as der(u) with an unknown u")
        raise self.error(self.unknown_name_message(name, node))

    def unknown_name_message(self, name: str, node: ast.AST) -> str:
        kinds = (("coordinates", self.coordinates), ("constants", tuple(self.constants)), ("unknowns", self.unknowns))
        listing = "".join(f"{kind}: {', '.join(names)}; " for kind, names in kinds if names)
        close = difflib.get_close_matches(name, [*self.coordinates, *self.constants, *self.unknowns, "pi"], n=1)
        hint = f"; did you mean '{close[0]}'?" if close else ""
        return f"unknown name {self.quote(node)} (known names: {listing}pi){hint}"

    def unknown_in_context(self, name: str, context: _Enclosing) -> ExpressionError:
        where = f"{_CONTEXT_PHRASES[context.kind]} {self.quote(context.node)}"
        why = {
            "argument": "functions of unknowns are not supported (equations must be polynomial in the unknowns)",
            "denominator": "division by an unknown is not supported",
            "exponent": "an exponent may not depend on unknowns",
        }[context.kind]
        return self.error(f"unknown '{name}' {where}: {why}")

    # -- operators -------------------------------------------------------------------------
    def visit_unary(self, node: ast.UnaryOp, context: _Enclosing | None) -> Polynomial:
        if isinstance(node.op, ast.USub):
            return -self.visit(node.operand, context)
        if isinstance(node.op, ast.UAdd):
            return self.visit(node.operand, context)
        raise self.disallowed_operator(node)

    def disallowed_operator(self, node: ast.BinOp | ast.UnaryOp) -> ExpressionError:
        symbol = _OPERATOR_SYMBOLS.get(type(node.op), type(node.op).__name__)
        hint = "; use ** for powers" if symbol == "^" else f"; {self.allowed()}"
        return self.error(f"operator '{symbol}' in {self.quote(node)} is not allowed{hint}")

    def visit_binary(self, node: ast.BinOp, context: _Enclosing | None) -> Polynomial:
        visitor = _BINARY_VISITORS.get(type(node.op))
        if visitor is None:
            raise self.disallowed_operator(node)
        # the left operand first, always: its errors come before the right one's
        return visitor(self, node, self.visit(node.left, context), context)

    def visit_add(self, node: ast.BinOp, left: Polynomial, context: _Enclosing | None) -> Polynomial:
        return left + self.visit(node.right, context)

    def visit_sub(self, node: ast.BinOp, left: Polynomial, context: _Enclosing | None) -> Polynomial:
        return left - self.visit(node.right, context)

    def visit_mul(self, node: ast.BinOp, left: Polynomial, context: _Enclosing | None) -> Polynomial:
        return self.multiply(left, self.visit(node.right, context), node)

    def visit_div(self, node: ast.BinOp, left: Polynomial, context: _Enclosing | None) -> Polynomial:
        if context is None and mentions(node.right, self.unknowns):  # 1/(1 + u): a general atom 1/(...)
            inverse = ast.BinOp(ast.Constant(1), ast.Div(), node.right)
            return self.multiply(left, self.general(node, inverse), node)
        return self.divide(left, self.visit(node.right, _Enclosing("denominator", node)), node)

    def visit_pow(self, node: ast.BinOp, left: Polynomial, context: _Enclosing | None) -> Polynomial:
        if context is None and mentions(node.right, self.unknowns):  # 2**u
            return self.general(node)
        return self.power(left, self.visit(node.right, _Enclosing("exponent", node)), node)

    def general(self, node: ast.AST, term: ast.AST | None = None) -> Polynomial:
        """``term`` (default: ``node``, the text quoted in errors), in which unknowns enter
        non-polynomially, as one general atom (:mod:`pgdcli.problem.general`)."""
        tree = build_tree(node if term is None else term, GeneralNames(self, node))
        return Polynomial.atom(Atom(render(tree), GENERAL, 0))

    def multiply(self, a: Polynomial, b: Polynomial, node: ast.AST) -> Polynomial:
        """``a*b``, refusing expansions that would blow up the number of terms or the work."""
        products = sum(len(s1.terms) * len(s2.terms) for s1 in a.values() for s2 in b.values())
        self.products += products
        if self.products > MAX_PRODUCTS:
            raise self.too_many_terms(node)
        result = a * b
        if result.term_count > MAX_TERMS:
            raise self.too_many_terms(node)
        return result

    def too_many_terms(self, node: ast.AST) -> ExpressionError:
        return self.error(f"expanding {self.quote(node)} gives too many separated terms (at most {MAX_TERMS})")

    # -- calls -----------------------------------------------------------------------------
    def visit_call(self, node: ast.Call, context: _Enclosing | None) -> Polynomial:
        if not isinstance(node.func, ast.Name):
            raise self.disallowed(node, "call")
        name = node.func.id
        if name == "der":
            return self.visit_der(node, context)
        if name not in FUNCTIONS:
            raise self.disallowed(node, "call")
        problem = call_problem(node)
        if problem:
            raise self.error(f"{self.quote(node)}: {problem}")
        if context is None and mentions(node, self.unknowns):
            return self.general(node)  # sin(th), max(u, 0): a function of unknowns
        enclosing = _Enclosing("argument", node)
        if len(node.args) == 1:
            argument = self.visit(node.args[0], enclosing)
            return Polynomial.from_separable(self.apply_function(name, argument.coefficient(()), node))
        arguments = [self.visit(arg, enclosing).coefficient(()) for arg in self.call_operands(node)]
        comparison = COMPARE_OPS[type(node.args[0].ops[0])] if name == "where" else None
        return Polynomial.from_separable(self.apply_multi(name, arguments, comparison, node))

    @staticmethod
    def call_operands(node: ast.Call) -> list:
        """The operands of a call: those of a where() condition in place of the condition."""
        if node.func.id == "where":
            condition = node.args[0]
            return [condition.left, condition.comparators[0], *node.args[1:]]
        return list(node.args)

    def visit_der(self, node: ast.Call, context: _Enclosing | None) -> Polynomial:
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


class GeneralNames:
    """Name resolution and errors of :func:`pgdcli.problem.general.build_tree` for one general term of a parse."""

    def __init__(self, parser: Parser, term: ast.AST) -> None:
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
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS and what:
            return parser.error(f"{parser.quote(node)}: {what}")
        if isinstance(node, (ast.BinOp, ast.UnaryOp)):
            return parser.disallowed_operator(node)
        return parser.disallowed(node, "call" if isinstance(node, ast.Call) else None)


_VISITORS = {
    ast.Constant: Parser.visit_constant,
    ast.Name: Parser.visit_name,
    ast.UnaryOp: Parser.visit_unary,
    ast.BinOp: Parser.visit_binary,
    ast.Call: Parser.visit_call,
}
_CHECKED = (ast.BinOp, ast.Call)
_BINARY_VISITORS = {
    ast.Add: Parser.visit_add,
    ast.Sub: Parser.visit_sub,
    ast.Mult: Parser.visit_mul,
    ast.Div: Parser.visit_div,
    ast.Pow: Parser.visit_pow,
}
