"""Tests of pgdcli.problem.trees: one evaluator for the three leaf formats of expression trees."""

from __future__ import annotations

import numpy as np

from pgdcli.problem.expressions import Separable, merge_to_function, parse_expression
from pgdcli.problem.general import evaluate, tree_names
from pgdcli.problem.trees import evaluate_tree, leaf_names, map_leaves, values_at, values_by_name

KW = dict(coordinates=["t", "k", "w"], constants={"g": 2.5}, unknowns=["u"], time="t", where="x.yaml")


def _sep(text: str) -> Separable:
    return parse_expression(text, **KW).coefficient(())


def test_one_coordinate_function_matches_numpy():
    k = np.random.default_rng(0).uniform(0.1, 3.0, 300)
    func = merge_to_function(_sep("sin(k)*exp(-k/2) + g*k**3 - 1/(1 + k**2)"))
    expected = np.sin(k) * np.exp(-k / 2) + 2.5 * k**3 - 1 / (1 + k**2)
    np.testing.assert_allclose(func(k), expected, rtol=1e-13, atol=1e-13)


def test_the_same_tree_with_named_leaves_gives_the_same_values():
    # a Func1D tree (leaf ('var',)) and the same tree with the leaf named (as in general terms):
    # one evaluator, two leaf callbacks
    k = np.random.default_rng(1).uniform(0.1, 3.0, 300)
    func = merge_to_function(_sep("cosh(k/3)**2*sqrt(k) - k/(2 + k)"))
    named = map_leaves(func.tree, lambda leaf: ("name", "k") if leaf == ("var",) else leaf)
    assert tree_names(named) == {"k"} and leaf_names(func.tree, "name") == frozenset()
    np.testing.assert_allclose(evaluate(named, {"k": k}), func(k), rtol=1e-14, atol=0)
    np.testing.assert_allclose(evaluate_tree(named, values_by_name({"k": k})), func(k), rtol=1e-14, atol=0)


def test_joint_tree_evaluates_by_coordinate_name():
    rng = np.random.default_rng(2)
    w, t = rng.uniform(0, 2, 300), rng.uniform(0, 5, 300)
    joint = _sep("3*k*sin(w*t)").joints[0]
    assert joint.tree_coordinates == {"w", "t"}
    np.testing.assert_array_equal(joint.evaluate_tree({"w": w, "t": t}), np.sin(w * t))
    np.testing.assert_allclose(joint.evaluate(k=2.0, w=w, t=t), 6.0 * np.sin(w * t), rtol=1e-15)
    fixed = joint.with_value("w", 0.5)
    assert fixed.tree_coordinates == {"t"}
    np.testing.assert_array_equal(fixed.evaluate_tree({"t": t}), np.sin(0.5 * t))


def test_one_variable_numbers_take_the_shape_of_the_points():
    # numbers are full arrays at x's shape: x**2 then rounds as it always did (numpy's power has a
    # faster, differently rounded path for a 0-d exponent)
    x = np.random.default_rng(3).uniform(0.1, 3.0, (4, 5))
    tree = ("pow", ("var",), ("num", 2.0))
    np.testing.assert_array_equal(evaluate_tree(tree, values_at(x)), np.power(x, np.full(x.shape, 2.0)))
    assert evaluate_tree(("num", 7.0), values_at(x)).shape == x.shape
    assert merge_to_function(Separable.constant(7.0))(x).shape == x.shape
    assert evaluate(("num", 7.0), {}).shape == ()
