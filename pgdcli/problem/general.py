"""General terms: functions of the unknowns as whitelisted expression trees.

The separated parser (:mod:`pgdcli.problem.expressions`) keeps equations polynomial in
the unknowns. A term in which an unknown enters non-polynomially (``sin(th)``,
``exp(-E/u)``, ``1/(1 + u)``, ``u**0.5``, ``sqrt(vx**2 + vy**2)``) cannot be
separated; it becomes a *general atom*: an :class:`~pgdcli.problem.expressions.Atom`
whose ``coordinate`` is :data:`GENERAL` and whose ``unknown`` is the canonical
text of an expression tree over coordinates and unknowns. The atom then
multiplies like an unknown, so ``-(g/L)*sin(th)`` is the monomial
``(sin(th),)`` with the separated coefficient ``-g/L`` and ``abs(v)*v`` the
monomial ``(abs(v), v)``: the polynomial part of an equation keeps its exact
path, and the general atoms beside it are evaluated pointwise by
:func:`evaluate`, a vectorized walk of the tree (never ``eval``).

Trees are those of :mod:`pgdcli.problem.trees` with leaves ``('name', name)``, evaluated
by its one evaluator. Constants are folded into numbers when the tree is built. The text
of an atom renders the tree with the fewest parentheses that parse back to the
same tree, so :func:`tree_of` recovers it from the atom alone (spec text never
reaches ``eval``: the text is parsed with ``ast`` against the same whitelist).
"""

from __future__ import annotations

import ast
import functools
import math
from typing import Iterable, Mapping

import numpy as np

from .trees import FUNCTIONS, arity, evaluate_tree, leaf_names, render_text, signature, values_by_name

__all__ = ["FUNCTIONS", "GENERAL", "is_general", "tree_of", "build_tree", "mentions", "render", "evaluate",
           "tree_names", "has_general", "call_problem", "condition_problem", "COMPARE_OPS"]

#: The ``coordinate`` of a general atom (not an identifier, so no coordinate can have it).
GENERAL = "<general>"

_BINARY_OPS = {ast.Add: "add", ast.Sub: "sub", ast.Mult: "mul", ast.Div: "div", ast.Pow: "pow"}
#: The comparisons a ``where`` condition may make, by syntax node.
COMPARE_OPS = {ast.Lt: "lt", ast.LtE: "le", ast.Gt: "gt", ast.GtE: "ge"}


# ----------------------------------------------------------------------------------------------
# atoms
# ----------------------------------------------------------------------------------------------
def is_general(atom) -> bool:
    """True for the :class:`~pgdcli.problem.expressions.Atom` of a general term: ``Atom(render(tree), GENERAL, 0)``."""
    return atom.coordinate == GENERAL


def has_general(polynomial) -> bool:
    """True if a monomial of the polynomial holds a general atom."""
    return any(is_general(atom) for atom in polynomial.atoms)


@functools.lru_cache(maxsize=1024)
def tree_of(atom) -> tuple:
    """The expression tree of a general atom (its text parsed back, whitelisted)."""
    if not is_general(atom):
        raise ValueError(f"{atom!r} is not a general atom")
    return build_tree(ast.parse(atom.unknown, mode="eval").body, _Names())


def mentions(node: ast.AST, names: Iterable[str]) -> bool:
    """True if the syntax tree uses one of the names (as a variable or inside der())."""
    names = set(names)
    return any(isinstance(n, ast.Name) and n.id in names for n in ast.walk(node))


# ----------------------------------------------------------------------------------------------
# building trees from whitelisted syntax
# ----------------------------------------------------------------------------------------------
class _Names:
    """Name resolution for re-parsing canonical text: every name is a variable."""

    constants: Mapping[str, float] = {}

    def resolve(self, node: ast.Name) -> tuple:
        return ("name", node.id)

    def refuse(self, node: ast.AST, what: str | None = None) -> Exception:
        return ValueError(f"not a canonical general term: {ast.unparse(node)}")


def build_tree(node: ast.AST, names) -> tuple:
    """Expression tree of a syntax tree, against the whitelist of the separated parser.

    Parameters
    ----------
    node : ast.AST
        An expression node (``ast.parse(text, mode='eval').body`` or part of it).
    names : object
        ``resolve(node: ast.Name) -> tree`` (a constant folds to ``('num', v)``, a
        coordinate or unknown to ``('name', n)``, anything else raises) and
        ``refuse(node, what=None) -> Exception`` for syntax outside the whitelist.

    Returns
    -------
    tuple
        The tree, numbers folded.
    """
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise names.refuse(node)
        value = float(node.value) if abs(node.value) < 1e308 else math.inf
        if not math.isfinite(value):
            raise names.refuse(node, "number too large:")
        return ("num", value)
    if isinstance(node, ast.Name):
        return names.resolve(node)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        child = build_tree(node.operand, names)
        return child if isinstance(node.op, ast.UAdd) else _fold(("neg", child))
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY_OPS:
        return _fold((_BINARY_OPS[type(node.op)], build_tree(node.left, names), build_tree(node.right, names)))
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS:
        problem = call_problem(node)
        if problem:
            raise names.refuse(node, problem)
        name = node.func.id
        children = [_condition_tree(arg, names) if name == "where" and k == 0 else build_tree(arg, names)
                    for k, arg in enumerate(node.args)]
        if name == "smoothstep" and children[0][0] == children[1][0] == "num" and children[0] == children[1]:
            raise names.refuse(node, "smoothstep(edge0, edge1, x) needs edge0 != edge1 (use step(x - edge0))")
        return _fold(("call", name, *children))
    raise names.refuse(node)


def call_problem(node: ast.Call) -> str:
    """What is wrong with the arguments of a call of a function of :data:`FUNCTIONS` ('' if nothing)."""
    name = node.func.id
    count = arity(name)
    if node.keywords or len(node.args) != count:
        plural = "one argument" if count == 1 else f"{count} arguments"
        return f"{name}() takes exactly {plural}: {signature(name)}"
    if name == "where":
        return condition_problem(node.args[0])
    return ""


def condition_problem(node: ast.AST) -> str:
    """What is wrong with the condition of ``where(condition, a, b)`` ('' if nothing)."""
    usage = "the condition of where(condition, a, b) must be one comparison with <, <=, > or >=, e.g. where(y < 0, a, b)"
    if not isinstance(node, ast.Compare):
        return usage
    if len(node.ops) != 1:
        return f"{usage}; nest where() for a range: where(x > 0, where(x < 1, a, b), b)"
    if type(node.ops[0]) not in COMPARE_OPS:
        return f"{usage}; equality of computed numbers is not reliable"
    return ""


def _condition_tree(node: ast.Compare, names) -> tuple:
    return (COMPARE_OPS[type(node.ops[0])], build_tree(node.left, names), build_tree(node.comparators[0], names))


def _fold(tree: tuple) -> tuple:
    """A node whose children are all numbers becomes a number (when finite)."""
    children = tree[2:] if tree[0] == "call" else tree[1:]
    if not all(child[0] == "num" for child in children):
        return tree
    with np.errstate(all="ignore"):
        value = float(evaluate(tree, {}))
    return ("num", value) if math.isfinite(value) else tree


# ----------------------------------------------------------------------------------------------
# evaluation and text
# ----------------------------------------------------------------------------------------------
def evaluate(tree: tuple, values: Mapping[str, np.ndarray | float]) -> np.ndarray:
    """The tree at points given per name (numpy broadcasting; NaN/inf where undefined).

    Parameters
    ----------
    tree : tuple
    values : mapping of str to ndarray or float
        Every name of the tree (:func:`tree_names`), arrays broadcastable together.

    Returns
    -------
    ndarray
        The broadcast shape of the values the tree uses (0-d for a number).
    """
    with np.errstate(all="ignore"):
        return evaluate_tree(tree, values_by_name(values))


def tree_names(tree: tuple) -> frozenset[str]:
    """Names (coordinates and unknowns) the tree uses."""
    return leaf_names(tree, "name")


def render(tree: tuple) -> str:
    """Text of a tree that parses back to the same tree (numbers exact: ``repr``)."""
    return render_text(tree, exact=True)
