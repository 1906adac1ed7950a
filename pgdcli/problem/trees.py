"""Expression trees: the one tree format of the problem layer, its evaluator, constructors and text.

Trees are tuples: ``('num', value)``, ``('call', function, *children)``, ``('neg', child)`` and
``(op, left, right)`` with op in ``add sub mul div pow`` (and the comparisons ``lt le gt ge``, only
as the condition of ``where``). Their leaves differ by use:

- ``('var',)``: the variable of a one-coordinate function (:class:`~pgdcli.problem.separable.Func1D`);
- ``('coord', name)``: a coordinate of a non-separable part (:class:`~pgdcli.problem.separable.Joint`);
- ``('name', name)``: a coordinate or unknown of a general term (:mod:`pgdcli.problem.general`).

:func:`evaluate_tree` is the one evaluator of all three: the node kinds are walked here, and a
leaf callback gives the values of the leaves. The solver, the march and the references all
evaluate a user's formula through it (that is expression evaluation, not solver numerics).
Spec text never reaches ``eval``/``exec``: trees are built from whitelisted ``ast`` nodes only.
"""

from __future__ import annotations

import math
from typing import Callable, Mapping

import numpy as np

__all__ = ["FUNCTIONS", "SIGNATURES", "NON_SMOOTH", "COMPARISONS", "arity", "signature", "calls", "BINARY", "evaluate_tree", "values_at", "values_by_name", "map_leaves", "leaf_names", "num",
           "num_value", "is_nonneg_int", "t_neg", "t_add", "t_mul", "t_div", "t_pow", "format_number", "render_text",
           "PRECEDENCE", "SYMBOL"]

def _clamp(x, lo, hi):
    return np.minimum(np.maximum(x, lo), hi)


def _step(x):
    # 1 where x >= 0, so that step(x) == where(x >= 0, 1, 0); NaN stays NaN
    return np.where(np.isnan(x), np.nan, np.where(x >= 0, 1.0, 0.0))


def _smoothstep(edge0, edge1, x):
    # the cubic Hermite step of shading languages: 0 below edge0, 1 above edge1, C1 in between
    s = _clamp((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def _where(condition, a, b):
    # a NaN condition (a comparison of NaN) gives NaN, not the second branch
    return np.where(np.isnan(condition), np.nan, np.where(condition != 0, a, b))


def _comparison(operation):
    """A comparison as 1.0 (true), 0.0 (false) or NaN (an operand is NaN), so that NaN is not hidden."""
    def compare(a, b):
        with np.errstate(invalid="ignore"):
            return np.where(np.isnan(a) | np.isnan(b), np.nan, operation(a, b) * 1.0)
    return compare


#: Functions allowed in expressions, with their numpy implementation (the parser's whitelist).
FUNCTIONS = {
    "sin": np.sin,
    "cos": np.cos,
    "tan": np.tan,
    "exp": np.exp,
    "log": np.log,
    "sqrt": np.sqrt,
    "sinh": np.sinh,
    "cosh": np.cosh,
    "tanh": np.tanh,
    "abs": np.abs,
    "sign": np.sign,
    "step": _step,
    "min": np.minimum,
    "max": np.maximum,
    "atan2": np.arctan2,
    "clamp": _clamp,
    "smoothstep": _smoothstep,
    "where": _where,
}

#: The signature of every function of more than one argument (the others take one, ``f(x)``).
SIGNATURES = {
    "min": ("a", "b"),
    "max": ("a", "b"),
    "atan2": ("y", "x"),
    "clamp": ("x", "lo", "hi"),
    "smoothstep": ("edge0", "edge1", "x"),
    "where": ("condition", "a", "b"),
}

#: Functions whose value or derivative jumps where an argument crosses a point (a kink): the
#: march's error control needs ever smaller steps there, and interpolation converges slowly
#: across it.
NON_SMOOTH = ("abs", "sign", "step", "min", "max", "clamp", "smoothstep", "where", "atan2")

#: The comparisons of a ``where`` condition, with their symbols.
COMPARISONS = {"lt": " < ", "le": " <= ", "gt": " > ", "ge": " >= "}


def arity(name: str) -> int:
    """Number of arguments of a function of :data:`FUNCTIONS`."""
    return len(SIGNATURES.get(name, ("x",)))


def signature(name: str) -> str:
    """The call a user writes, e.g. ``clamp(x, lo, hi)``."""
    return f"{name}({', '.join(SIGNATURES.get(name, ('x',)))})"


#: The binary node kinds and their numpy functions.
BINARY: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "add": np.add,
    "sub": np.subtract,
    "mul": np.multiply,
    "div": np.divide,
    "pow": np.power,
    "lt": _comparison(np.less),
    "le": _comparison(np.less_equal),
    "gt": _comparison(np.greater),
    "ge": _comparison(np.greater_equal),
}


# ----------------------------------------------------------------------------------------------
# evaluation and walks
# ----------------------------------------------------------------------------------------------
def evaluate_tree(tree: tuple, leaf: Callable[[tuple], np.ndarray],
                  functions: Mapping[str, Callable] = FUNCTIONS) -> np.ndarray:
    """The tree's value, numpy-vectorized (NaN/inf or numpy warnings where undefined).

    Parameters
    ----------
    tree : tuple
    leaf : callable
        ``leaf(node) -> array`` for every leaf: numbers (``('num', v)``) and variables
        (``('var',)``, ``('coord', n)``, ``('name', n)``); arrays broadcastable together.
        :func:`values_at` and :func:`values_by_name` make the two in use.
    functions : mapping, optional
        The functions of ``call`` nodes (derivative trees add ``sign``:
        :data:`pgdcli.problem.derivative.DERIVATIVE_FUNCTIONS`).

    Returns
    -------
    ndarray or numpy scalar
        The broadcast shape of the leaves' values.
    """
    kind = tree[0]
    if kind == "call":
        return functions[tree[1]](*(evaluate_tree(child, leaf, functions) for child in tree[2:]))
    if kind == "neg":
        return np.negative(evaluate_tree(tree[1], leaf, functions))
    operation = BINARY.get(kind)
    if operation is None:
        return leaf(tree)
    return operation(evaluate_tree(tree[1], leaf, functions), evaluate_tree(tree[2], leaf, functions))


def values_at(x: np.ndarray) -> Callable[[tuple], np.ndarray]:
    """The leaf callback of a one-variable tree at the points x (a float array).

    Numbers are filled to the shape of x: numpy's power takes a faster path for a 0-d
    exponent (``x**2`` as ``x*x``), which rounds differently from the full array.
    """
    shape = np.shape(x)
    return lambda node: x if node[0] == "var" else np.full(shape, node[1])


def values_by_name(values: Mapping[str, np.ndarray | float]) -> Callable[[tuple], np.ndarray]:
    """The leaf callback of named leaves (``('coord', n)``, ``('name', n)``): ``values[n]`` as floats,
    numbers 0-d."""
    return lambda node: np.asarray(node[1]) if node[0] == "num" else np.asarray(values[node[1]], dtype=float)


def map_leaves(tree: tuple, replace: Callable[[tuple], tuple]) -> tuple:
    """The tree with every leaf (not a number) replaced by ``replace(leaf)`` (not simplified)."""
    kind = tree[0]
    if kind == "num":
        return tree
    if kind == "call":
        return ("call", tree[1], *(map_leaves(child, replace) for child in tree[2:]))
    if kind == "neg" or kind in BINARY:
        return (kind,) + tuple(map_leaves(child, replace) for child in tree[1:])
    return replace(tree)


def calls(tree: tuple, names) -> bool:
    """True if the tree calls one of the functions ``names``."""
    if tree[0] == "call" and tree[1] in names:
        return True
    children = tree[2:] if tree[0] == "call" else tree[1:] if tree[0] == "neg" or tree[0] in BINARY else ()
    return any(calls(child, names) for child in children)


def leaf_names(tree: tuple, kind: str) -> frozenset[str]:
    """Names of the leaves ``(kind, name)`` of a tree (``kind``: 'coord' or 'name')."""
    if tree[0] == kind:
        return frozenset((tree[1],))
    if tree[0] == "call":
        return frozenset().union(*(leaf_names(child, kind) for child in tree[2:]))
    if tree[0] == "neg" or tree[0] in BINARY:
        return frozenset().union(*(leaf_names(child, kind) for child in tree[1:]))
    return frozenset()


# ----------------------------------------------------------------------------------------------
# smart constructors: numbers folded, identities removed, so that equal functions build equal trees
# ----------------------------------------------------------------------------------------------
def num(value: float) -> tuple:
    """Leaf node of a number."""
    return ("num", float(value))


def num_value(tree: tuple) -> float | None:
    """The number of a ``num`` leaf, else None."""
    return tree[1] if tree[0] == "num" else None


def is_nonneg_int(value: float | None) -> bool:
    return value is not None and value >= 0 and float(value).is_integer()


def t_neg(a: tuple) -> tuple:
    va = num_value(a)
    if va is not None:
        return num(-va)
    if a[0] == "neg":
        return a[1]
    return ("neg", a)


def t_add(a: tuple, b: tuple) -> tuple:
    va, vb = num_value(a), num_value(b)
    if va is not None and vb is not None:
        return num(va + vb)
    if va == 0:
        return b
    if vb == 0:
        return a
    # "t - 3" reads better than "t + -3"
    if vb is not None and vb < 0:
        return ("sub", a, num(-vb))
    if b[0] == "neg":
        return ("sub", a, b[1])
    if b[0] == "mul" and (num_value(b[1]) or 0) < 0:
        return ("sub", a, t_mul(num(-b[1][1]), b[2]))
    return ("add", a, b)


def _int_power(tree: tuple) -> tuple[tuple, int | None]:
    """Split ``base**n`` with a non-negative integer n; other trees are ``tree**1``."""
    if tree[0] == "pow" and is_nonneg_int(num_value(tree[2])):
        return tree[1], int(tree[2][1])
    if tree[0] == "num":
        return tree, None
    return tree, 1


def t_mul(a: tuple, b: tuple) -> tuple:
    va, vb = num_value(a), num_value(b)
    if va is not None and vb is not None:
        return num(va * vb)
    for v, other in ((va, b), (vb, a)):
        if v == 1:
            return other
        if v == -1:
            return t_neg(other)
    # a * (1/b) -> a/b, which reads better and saves an operation
    if b[0] == "div" and num_value(b[1]) == 1:
        return t_div(a, b[2])
    if a[0] == "div" and num_value(a[1]) == 1:
        return t_div(b, a[2])
    # x**m * x**n -> x**(m+n) only for non-negative integer m, n: exact for every real x
    base_a, n_a = _int_power(a)
    base_b, n_b = _int_power(b)
    if n_a is not None and n_b is not None and base_a == base_b:
        return t_pow(base_a, num(n_a + n_b))
    # numbers first, so that 2*t and t*2 build the same tree
    if vb is not None:
        return ("mul", b, a)
    return ("mul", a, b)


def t_div(a: tuple, b: tuple) -> tuple:
    if num_value(b) == 1:
        return a
    # x**m / x**n -> x**(m-n) for non-negative integers: k*a/k must not keep a
    # removable singularity at k = 0 (nor cost an extra operation)
    base_a, m = _int_power(a)
    base_b, n = _int_power(b)
    if m is not None and n is not None and base_a == base_b:
        if m >= n:
            return t_pow(base_a, num(m - n))
        return ("div", num(1.0), t_pow(base_a, num(n - m)))
    # 1/(1/g) = g, which keeps repeated inversion from nesting
    if num_value(a) == 1 and b[0] == "div" and num_value(b[1]) == 1:
        return b[2]
    return ("div", a, b)


def t_pow(a: tuple, b: tuple) -> tuple:
    vb = num_value(b)
    if vb == 1:
        return a
    if vb == 0:
        return num(1.0)
    if vb == -1:
        return t_div(num(1.0), a)
    return ("pow", a, b)


# ----------------------------------------------------------------------------------------------
# text: for people (fewest parentheses that read right) or exact (parses back to the same tree)
# ----------------------------------------------------------------------------------------------
#: Python precedences, so that rendered text parses back to the same tree
PRECEDENCE = {**dict.fromkeys(COMPARISONS, 0), "add": 1, "sub": 1, "mul": 2, "div": 2, "neg": 3, "pow": 4}
SYMBOL = {**COMPARISONS, "add": " + ", "sub": " - ", "mul": "*", "div": "/", "pow": "**"}
# least precedence of the (left, right) operands written without parentheses; the exact text
# also keeps a + (b + c) and a*(b*c), which are other trees than (a + b) + c and (a*b)*c
_OPERANDS = {**dict.fromkeys(COMPARISONS, (1, 1)), "add": (1, 1), "sub": (1, 2), "mul": (2, 2), "div": (2, 3), "pow": (5, 3)}
_OPERANDS_EXACT = {**_OPERANDS, "add": (1, 2), "mul": (2, 3)}


def format_number(value: float) -> str:
    """Shortest text of a number: integers without '.0'."""
    if float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(float(value))


def _negative_zero(value: float) -> bool:
    return value == 0.0 and math.copysign(1.0, value) < 0


def _tree_precedence(tree: tuple, exact: bool) -> int:
    if tree[0] == "num":
        negative = math.copysign(1.0, tree[1]) < 0 if exact else tree[1] < 0  # exact: -0.0 too
        return 3 if negative else 5
    return PRECEDENCE.get(tree[0], 5)  # leaves and calls bind tightest


def render_text(tree: tuple, name: str = "?", min_precedence: int = 0, *, exact: bool = False) -> str:
    """Text of a tree (``('var',)`` written ``name``), in parentheses if it binds less tightly than required.

    With ``exact`` the text parses back to the same tree, numbers to the same float (-0.0 too):
    the canonical text of a general term (:func:`pgdcli.problem.general.render`).
    """
    text = _render_bare(tree, name, exact)
    return f"({text})" if _tree_precedence(tree, exact) < min_precedence else text


def _render_bare(tree: tuple, name: str, exact: bool) -> str:
    kind = tree[0]
    if kind == "num":
        return repr(tree[1]) if exact and _negative_zero(tree[1]) else format_number(tree[1])
    if kind == "var":
        return name
    if kind in ("coord", "name"):
        return tree[1]
    if kind == "call":
        return f"{tree[1]}({', '.join(render_text(child, name, exact=exact) for child in tree[2:])})"
    if kind == "neg":
        return "-" + render_text(tree[1], name, 4, exact=exact)
    left, right = (_OPERANDS_EXACT if exact else _OPERANDS)[kind]
    return render_text(tree[1], name, left, exact=exact) + SYMBOL[kind] + render_text(tree[2], name, right, exact=exact)
