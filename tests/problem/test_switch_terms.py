"""Switching terms in expressions: min, max, clamp, sign, step, smoothstep, atan2 and where(condition, a, b).

Values are checked against pointwise Python formulas written here (math and plain comparisons), not
against the numpy functions the evaluator uses.
"""

from __future__ import annotations

import ast
import math

import numpy as np
import pytest

from conftest import spec_text
from cli_refusal import assert_refused_in_one_line
from pgdcli.errors import ExpressionError
from pgdcli.problem.expressions import Atom, Func1D, parse_expression
from pgdcli.problem.general import build_tree, evaluate, is_general, render, tree_of
from pgdcli.problem.trees import NON_SMOOTH, calls

KW = dict(coordinates=["t", "a", "k"], constants={"g": 9.81}, unknowns=["u", "v"], time="t", where="p.yaml: equations[1]")


def _smoothstep(e0, e1, x):
    s = min(max((x - e0) / (e1 - e0), 0.0), 1.0)
    return s * s * (3 - 2 * s)


#: text -> pointwise formula of (u, v)
FORMULAS = {
    "max(u, 0)": lambda u, v: u if u > 0 else 0.0,
    "min(u, v)": lambda u, v: u if u < v else v,
    "clamp(u, -0.5, 0.25)": lambda u, v: -0.5 if u < -0.5 else (0.25 if u > 0.25 else u),
    "sign(u)": lambda u, v: 1.0 if u > 0 else (-1.0 if u < 0 else 0.0),
    "step(u)": lambda u, v: 1.0 if u >= 0 else 0.0,
    "smoothstep(-0.5, 0.5, u)": lambda u, v: _smoothstep(-0.5, 0.5, u),
    "atan2(v, u)": lambda u, v: math.atan2(v, u),
    "where(u < v, u*v, 2 - v)": lambda u, v: u * v if u < v else 2 - v,
    "where(u >= 0, 1, -1)": lambda u, v: 1.0 if u >= 0 else -1.0,
    "where(u <= 0, 1, -1)": lambda u, v: 1.0 if u <= 0 else -1.0,
    "where(u > -v, u, 0)": lambda u, v: u if u > -v else 0.0,
}


def _general_tree(text):
    poly = parse_expression(text, **KW)
    ((monomial, sep),) = poly.items()
    (atom,) = monomial
    assert is_general(atom) and sep.constant_value == 1.0
    return tree_of(atom)


@pytest.mark.parametrize("text", list(FORMULAS))
def test_functions_of_unknowns_are_general_atoms_with_the_right_values(text):
    rng = np.random.default_rng(3)
    u = np.concatenate([rng.uniform(-1, 1, 200), [0.0, -0.5, 0.25, 0.5]])
    v = np.concatenate([rng.uniform(-1, 1, 200), [0.0, 0.0, 0.25, 0.5]])
    tree = _general_tree(text)
    values = evaluate(tree, {"u": u, "v": v})
    expected = [FORMULAS[text](float(x), float(y)) for x, y in zip(u, v)]
    np.testing.assert_allclose(values, expected, rtol=1e-15, atol=1e-15)
    assert calls(tree, NON_SMOOTH)


@pytest.mark.parametrize("text", ["max(u, 0)", "where(u < v, u*v, 2 - v)", "clamp(u, -0.5, 0.25)",
                                  "smoothstep(-0.5, 0.5, u)", "where(-u >= -(v - 1), atan2(v, u), min(u, v))"])
def test_canonical_text_parses_back_to_the_same_tree(text):
    tree = _general_tree(text)

    class Names:
        def resolve(self, node):
            return ("name", node.id)

        def refuse(self, node, what=None):
            return ValueError(ast.unparse(node))

    assert build_tree(ast.parse(render(tree), mode="eval").body, Names()) == tree
    assert tree_of(Atom(render(tree), "<general>", 0)) == tree


def test_nan_is_not_hidden_by_a_condition_or_a_step():
    for text in ("where(u < 0, 1, 2)", "step(u)", "max(u, 0)", "clamp(u, 0, 1)"):
        assert np.isnan(evaluate(_general_tree(text), {"u": np.nan, "v": 0.0})), text


def test_a_coefficient_of_the_unknowns_keeps_its_separated_form():
    poly = parse_expression("-k*max(u, 0)*v", **KW)
    ((monomial, sep),) = poly.items()
    assert sorted(a.unknown for a in monomial) == ["max(u, 0)", "v"]
    np.testing.assert_allclose(sep.evaluate(k=np.array([2.0])), [-2.0])


@pytest.mark.parametrize("text, formula", [
    ("max(t - 0.5, 0)", lambda t, a: max(t - 0.5, 0.0)),
    ("step(t - 0.5)*a", lambda t, a: a if t >= 0.5 else 0.0),
    ("where(t < 1, t, 2 - t)", lambda t, a: t if t < 1 else 2 - t),
    ("max(t - a, 0)", lambda t, a: max(t - a, 0.0)),
    ("where(t < a, 1, smoothstep(a, a + 0.5, t))", lambda t, a: 1.0 if t < a else _smoothstep(a, a + 0.5, t)),
    ("atan2(a, t - 1) + clamp(t, a, 1.5)", lambda t, a: math.atan2(a, t - 1) + min(max(t, a), 1.5)),
])
def test_functions_of_coordinates_are_separated_terms(text, formula):
    poly = parse_expression(text, **KW)
    ((monomial, sep),) = poly.items()
    assert monomial == ()
    rng = np.random.default_rng(5)
    t, a = rng.uniform(0, 2, 300), rng.uniform(0.2, 1.2, 300)
    np.testing.assert_allclose(sep.evaluate(t=t, a=a), [formula(x, y) for x, y in zip(t, a)], rtol=1e-14, atol=1e-15)


def test_a_function_of_one_coordinate_stays_a_function_of_it():
    ((_, sep),) = parse_expression("max(t - 0.5, 0)", **KW).items()
    assert not sep.joints and len(sep.terms) == 1
    ((name, func),) = sep.terms[0].factors
    assert name == "t" and isinstance(func, Func1D) and str(func) == "max(t - 0.5, 0)"


def test_constant_arguments_fold_to_a_number():
    for text, value in (("max(2, g)", 9.81), ("min(-1, 3)", -1.0), ("clamp(5, 0, 1)", 1.0), ("step(0)", 1.0),
                        ("sign(-g)", -1.0), ("where(g > 10, 1, 2)", 2.0), ("atan2(1, 1)", math.pi / 4),
                        ("smoothstep(0, 2, 1)", 0.5)):
        ((monomial, sep),) = parse_expression(text, **KW).items()
        assert monomial == () and sep.constant_value == pytest.approx(value, rel=1e-15), text


@pytest.mark.parametrize("text, fragment", [
    ("max(u)", "max() takes exactly 2 arguments: max(a, b)"),
    ("min(u, v, 1)", "min() takes exactly 2 arguments"),
    ("clamp(u, 1)", "clamp(x, lo, hi)"),
    ("atan2(u)", "atan2(y, x)"),
    ("smoothstep(u, 1)", "smoothstep(edge0, edge1, x)"),
    ("sign(u, v)", "sign() takes exactly one argument"),
    ("max(a=u, b=0)", "max() takes exactly 2 arguments"),
    ("where(u, 1, 2)", "must be one comparison"),
    ("where(u == 0, 1, 2)", "equality of computed numbers is not reliable"),
    ("where(u != 0, 1, 2)", "must be one comparison"),
    ("where(0 < u < 1, 1, 2)", "nest where() for a range"),
    ("where(u < 1 and u > 0, 1, 2)", "must be one comparison"),
    ("where(u < 1, 1)", "where() takes exactly 3 arguments"),
    ("u < 1", "comparison 'u < 1' is not allowed"),
    ("max(u < 1, 0)", "comparison"),
    ("smoothstep(1, 1, u)", "needs edge0 != edge1"),
    ("smoothstep(g, g, t)", "needs edge0 != edge1"),
    ("sin(max(u, 0), 1)", "sin() takes exactly one argument"),
    ("exp(max(u))", "max() takes exactly 2 arguments"),
])
def test_bad_calls_are_refused_with_the_key_and_the_call(text, fragment):
    with pytest.raises(ExpressionError) as info:
        parse_expression(text, **KW)
    message = str(info.value)
    assert message.startswith("p.yaml: equations[1]: ") and fragment in message, message


def test_cli_refuses_a_bad_arity_in_one_line(tmp_path):
    spec = tmp_path / "bad.yaml"
    spec.write_text(spec_text(equations=["der(u) = -max(u)"]))
    assert_refused_in_one_line(spec, tmp_path / "bad.h5", "bad.yaml: equations[0]: 'max(u)'")


def _equations(*texts):
    import pgdcli

    body = "".join(f"\n  - \"{text}\"" for text in texts)
    spec = ("coordinates:\n  t: {domain: [0, 3]}\n  a: {domain: [0, 1]}\nunknowns:\n  u: {initial: 0}\n  v: {initial: 0}\n"
            f"equations:{body}")
    return pgdcli.parse_spec(spec, source="s.yaml").equations


def test_switch_points_are_the_zeros_of_the_switch_arguments():
    from pgdcli.problem.switches import switch_points

    equations = _equations("der(u) = -u + clamp(t - 1, 0, 0.5) + where(t**2 < 5, 1, 0)", "der(v) = sign(a - 1/3)")
    np.testing.assert_allclose(switch_points(equations, "t", (0.0, 3.0)), [1.0, 1.5, math.sqrt(5)], atol=1e-12)
    np.testing.assert_allclose(switch_points(equations, "a", (0.0, 1.0)), [1 / 3], atol=1e-12)
    assert switch_points(_equations("der(u) = step(sin(50*t))", "der(v) = 0"), "t", (0.0, 3.0)) == []  # too many


def test_time_switches_are_those_of_time_and_parameters_only():
    from pgdcli.problem.general import render
    from pgdcli.problem.switches import time_switches

    equations = _equations("der(u) = -u + max(t - a, 0) + max(u, 0)", "der(v) = step(t - 1)*v + min(a, 0.5)")
    assert sorted(render(tree) for tree in time_switches(equations, "t", ["u", "v"])) == ["t - 1", "t - a"]
