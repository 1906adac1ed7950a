"""Derivatives of expression trees (pgdcli.problem.derivative): the switching functions against
central finite differences of their values, away from their switches, and the piecewise rules at
the switch (one side's derivative, never NaN)."""

from __future__ import annotations

import ast

import numpy as np
import pytest

from pgdcli.problem.derivative import derivative
from pgdcli.problem.general import build_tree, evaluate

#: expressions of the unknowns u, v with their switching functions, and where they switch (the FD
#: stencil must stay off it)
SWITCHES = {
    "max(u, 0.2)*v": lambda u, v: [u - 0.2],
    "min(u*v, sin(u))": lambda u, v: [u * v - np.sin(u)],
    "clamp(u + v, -0.5, 0.25)": lambda u, v: [u + v + 0.5, u + v - 0.25],
    "clamp(u, v, 0.8)": lambda u, v: [u - v, u - 0.8],
    "sign(u)*v**2 + step(v - u)*u": lambda u, v: [u, v - u],
    "smoothstep(-0.5, 0.5, u*v)": lambda u, v: [u * v + 0.5, u * v - 0.5],
    "smoothstep(v, 1.5, u)": lambda u, v: [u - v, u - 1.5],
    "atan2(v, u)": lambda u, v: [np.where(u < 0, v, 1.0)],
    "atan2(u**2 + 0.1, v - 2*u)": lambda u, v: [np.ones_like(u)],
    "where(u < v, u*v, exp(v) - u)": lambda u, v: [u - v],
    "where(u**2 >= 0.25, cos(v), v*u)*max(v, -u)": lambda u, v: [u ** 2 - 0.25, v + u],
    "abs(min(u, v)) + max(-u, 2*v)**2": lambda u, v: [u - v, np.minimum(u, v), -u - 2 * v],
}


class _Names:
    """Names of the text as ``('name', n)`` leaves (the leaves of general terms)."""

    def resolve(self, node):
        return ("name", node.id)

    def refuse(self, node, what=None):
        return ValueError(ast.unparse(node))


def _tree(text):
    return build_tree(ast.parse(text, mode="eval").body, _Names())


@pytest.mark.parametrize("text", list(SWITCHES))
def test_derivatives_of_switching_functions_match_finite_differences(text):
    tree = _tree(text)
    rng = np.random.default_rng(5)
    u, v = rng.uniform(-1.2, 1.2, 4000), rng.uniform(-1.2, 1.2, 4000)
    step = 1e-6
    for name in ("u", "v"):
        slope = evaluate(derivative(tree, ("name", name)), {"u": u, "v": v})
        up = {"u": u, "v": v, name: (u, v)[name == "v"] + step}
        down = {"u": u, "v": v, name: (u, v)[name == "v"] - step}
        fd = (evaluate(tree, up) - evaluate(tree, down)) / (2 * step)
        # off every switch by far more than the stencil (the switch arguments move by O(step))
        away = np.all([np.abs(s) > 1e-3 for s in SWITCHES[text](u, v)], axis=0)
        assert away.sum() > 3000
        np.testing.assert_allclose(np.broadcast_to(slope, u.shape)[away], fd[away], rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("text, at, expected", [
    ("max(u, v)", (0.3, 0.3), {"u": 1.0, "v": 0.0}),  # a tie: the first argument's, as np.maximum
    ("min(u, v)", (0.3, 0.3), {"u": 1.0, "v": 0.0}),
    ("clamp(u, -1, 1)", (1.0, 0.0), {"u": 1.0, "v": 0.0}),
    ("where(u < v, 2*u, 3*v)", (0.5, 0.5), {"u": 0.0, "v": 3.0}),  # the branch in force
    ("sign(u)*v + step(u)", (0.0, 2.0), {"u": 0.0, "v": 0.0}),
    ("abs(u)", (0.0, 0.0), {"u": 0.0, "v": 0.0}),
])
def test_derivative_at_a_switch_is_one_sides(text, at, expected):
    tree = _tree(text)
    values = {"u": np.array(at[0]), "v": np.array(at[1])}
    for name, slope in expected.items():
        assert float(evaluate(derivative(tree, ("name", name)), values)) == slope


def test_a_term_switching_only_in_its_condition_has_a_zero_derivative_tree():
    assert derivative(_tree("where(u < 0, 1, -1)"), ("name", "u")) == ("num", 0.0)
    assert derivative(_tree("step(u - v)"), ("name", "v")) == ("num", 0.0)
    assert derivative(_tree("max(u, 0)"), ("name", "v")) == ("num", 0.0)
