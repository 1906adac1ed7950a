"""Derivatives of expression trees: ``d tree / d leaf`` as another tree.

The Jacobian of a general term (``sin(th)``, ``sqrt(vx**2 + vy**2)*vx``) in an unknown is its tree
differentiated in that unknown's leaf, by the rules of calculus and the smart constructors of
:mod:`pgdcli.problem.trees` (numbers folded, so a term that does not depend on the leaf gives
``num(0)``).

The switching functions are differentiated piecewise, as ``where`` terms that pick the derivative
of the branch in force: ``d min(a, b) = where(a <= b, da, db)``, ``d where(c, a, b) = where(c, da,
db)``, ``d abs(u) = sign(u) du``; ``sign`` and ``step`` have derivative 0, and ``clamp`` and
``smoothstep`` are differentiated through their definitions by ``min``, ``max`` and ``clamp``. At
the switch itself the derivative is one side's: a linearly implicit step needs its Jacobian only
to converge, and no step straddles a switch of time (:mod:`pgdcli.algorithms.switch_location`).
"""

from __future__ import annotations

from .trees import BINARY, COMPARISONS, FUNCTIONS, leaf_names, num, num_value, t_add, t_div, t_mul, t_neg, t_pow

__all__ = ["DERIVATIVE_FUNCTIONS", "derivative"]

#: The functions of derivative trees: the spec's (``sign``, the derivative of ``abs``, among them).
DERIVATIVE_FUNCTIONS = FUNCTIONS


def _call(name: str, *args: tuple) -> tuple:
    return ("call", name, *args)


#: d f(u) / d u for every function of the spec language, as a tree in ``u``.
_OUTER = {
    "sin": lambda u: _call("cos", u),
    "cos": lambda u: t_neg(_call("sin", u)),
    "tan": lambda u: t_div(num(1.0), t_pow(_call("cos", u), num(2.0))),
    "exp": lambda u: _call("exp", u),
    "log": lambda u: t_div(num(1.0), u),
    "sqrt": lambda u: t_div(num(0.5), _call("sqrt", u)),
    "sinh": lambda u: _call("cosh", u),
    "cosh": lambda u: _call("sinh", u),
    "tanh": lambda u: t_add(num(1.0), t_neg(t_pow(_call("tanh", u), num(2.0)))),
    "abs": lambda u: _call("sign", u),
    "sign": lambda u: num(0.0),
    "step": lambda u: num(0.0),
}


def _times(a: tuple, b: tuple) -> tuple:
    """``a * b``, zero when either is the number 0 (the smart constructor keeps ``0 * x``)."""
    return num(0.0) if num_value(a) == 0 or num_value(b) == 0 else t_mul(a, b)


def derivative(tree: tuple, leaf: tuple) -> tuple:
    """``d tree / d leaf`` (``leaf`` such as ``('name', 'u')``): a tree, ``num(0)`` where it does not depend on it."""
    if leaf[1] not in leaf_names(tree, leaf[0]):
        return num(0.0)
    kind = tree[0]
    if kind == leaf[0]:
        return num(1.0)
    if kind == "call" and len(tree) > 3 or kind in COMPARISONS:
        return _switch_derivative(tree, leaf)
    if kind == "call":
        return _times(_OUTER[tree[1]](tree[2]), derivative(tree[2], leaf))
    if kind == "neg":
        return t_neg(derivative(tree[1], leaf))
    if kind not in BINARY:
        raise ValueError(f"cannot differentiate a tree of kind {kind!r}")
    a, b = tree[1], tree[2]
    da, db = derivative(a, leaf), derivative(b, leaf)
    if kind in ("add", "sub"):
        return t_add(da, db if kind == "add" else t_neg(db))
    if kind == "mul":
        return t_add(_times(da, b), _times(a, db))
    if kind == "div":  # da/b - a db/b^2
        first = num(0.0) if num_value(da) == 0 else t_div(da, b)
        return first if num_value(db) == 0 else t_add(first, t_neg(t_div(_times(a, db), t_mul(b, b))))
    if num_value(db) == 0:  # a^c: c a^(c-1) da
        exponent = num(b[1] - 1.0) if b[0] == "num" else t_add(b, num(-1.0))
        return _times(t_mul(b, t_pow(a, exponent)), da)
    # a^b = exp(b log a): a^b (db log a + b da / a)
    return t_mul(tree, t_add(_times(db, _call("log", a)), t_div(_times(b, da), a)))


def _pick(condition: tuple, da: tuple, db: tuple) -> tuple:
    """``where(condition, da, db)``, folded when both branches are one number."""
    if da == db and da[0] == "num":
        return da
    return _call("where", condition, da, db)


def _switch_derivative(tree: tuple, leaf: tuple) -> tuple:
    """The derivative of a function of several arguments (or of a comparison: 0) in ``leaf``."""
    if tree[0] in COMPARISONS:  # a condition is piecewise constant
        return num(0.0)
    name, args = tree[1], tree[2:]
    if name == "clamp":  # min(max(x, lo), hi)
        x, lo, hi = args
        return derivative(_call("min", _call("max", x, lo), hi), leaf)
    if name == "smoothstep":  # s^2 (3 - 2 s), s = clamp((x - e0)/(e1 - e0), 0, 1)
        e0, e1, x = args
        s = _call("clamp", t_div(t_add(x, t_neg(e0)), t_add(e1, t_neg(e0))), num(0.0), num(1.0))
        return derivative(t_mul(t_mul(s, s), t_add(num(3.0), t_neg(t_mul(num(2.0), s)))), leaf)
    if name == "where":
        condition, a, b = args
        return _pick(condition, derivative(a, leaf), derivative(b, leaf))
    a, b = args
    da, db = derivative(a, leaf), derivative(b, leaf)
    if name in ("min", "max"):  # np.minimum/np.maximum: the first argument at a tie, as where(a <= b, ...)
        return _pick(("le" if name == "min" else "ge", a, b), da, db)
    if name == "atan2":  # atan2(y, x): (x dy - y dx) / (x^2 + y^2)
        y, x = a, b
        top = t_add(_times(x, da), t_neg(_times(y, db)))
        return top if num_value(top) == 0 else t_div(top, t_add(t_mul(x, x), t_mul(y, y)))
    raise ValueError(f"cannot differentiate the function {name!r}")
