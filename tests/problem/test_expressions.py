"""Tests of pgdcli.problem.expressions: safe parsing into separated (sum-of-products) form."""

from __future__ import annotations

import ast
import builtins
import pathlib
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pgdcli.errors import ExpressionError, SpecError
from pgdcli.problem.expressions import (
    MAX_TERMS,
    Atom,
    Func1D,
    Polynomial,
    SepTerm,
    Separable,
    evaluate_constant,
    format_monomial,
    make_monomial,
    merge_to_function,
    parse_equation,
    parse_expression,
)

WHERE = "problems/x.yaml: equations[1]"
KW = dict(coordinates=["t", "k", "a"], constants={"g": 9.81}, unknowns=["u", "v"], time="t", where=WHERE)


def parse(text: str, **overrides) -> Polynomial:
    return parse_expression(text, **{**KW, **overrides})


def separable(text: str) -> Separable:
    poly = parse(text)
    assert poly.degree == 0, text
    return poly.coefficient(())


def points(n: int = 50, seed: int = 0) -> dict[str, np.ndarray]:
    """Random points inside domains where every formula below is real and finite."""
    rng = np.random.default_rng(seed)
    return {"t": rng.uniform(0, 2, n), "k": rng.uniform(0.5, 5, n), "a": rng.uniform(0.2, 1, n)}


def error_of(text: str, **overrides) -> str:
    with pytest.raises(ExpressionError) as info:
        parse(text, **overrides)
    message = str(info.value)
    assert message.startswith(WHERE + ": ")
    assert "\n" not in message
    return message


# ----------------------------------------------------------------------------------------------
# numbers: separated forms evaluate to the same values as the formula written in numpy
# ----------------------------------------------------------------------------------------------
FORMULAS = [
    ("k*exp(-t) + 3/(a*k)", lambda t, k, a: k * np.exp(-t) + 3 / (a * k)),
    ("exp(-k - 2*a)", lambda t, k, a: np.exp(-k - 2 * a)),
    ("t**2 - 3*t", lambda t, k, a: t**2 - 3 * t),
    ("(t + k)**2", lambda t, k, a: (t + k) ** 2),
    ("(k + 1)/(k + 2)", lambda t, k, a: (k + 1) / (k + 2)),
    ("2**(k + a)", lambda t, k, a: 2 ** (k + a)),
    ("(k*a)**0.5", lambda t, k, a: (k * a) ** 0.5),
    ("abs(k*a - 0*t)", lambda t, k, a: np.abs(k * a)),
    ("sin(pi*t)*cos(k) + g", lambda t, k, a: np.sin(np.pi * t) * np.cos(k) + 9.81),
    ("(t + k + a)**3", lambda t, k, a: (t + k + a) ** 3),
    ("-(t + 1)/(2*k)", lambda t, k, a: -(t + 1) / (2 * k)),
    ("sqrt(k)*log(1 + t)", lambda t, k, a: np.sqrt(k) * np.log(1 + t)),
    ("tanh(a) + sinh(t) - cosh(k) + tan(a)", lambda t, k, a: np.tanh(a) + np.sinh(t) - np.cosh(k) + np.tan(a)),
    ("k**-2 + 1/(1/t)", lambda t, k, a: k**-2.0 + t),
    ("(k + a)*(k + 1)/k", lambda t, k, a: (k + a) * (k + 1) / k),
    ("exp(3*k - 2 + t)/a**2", lambda t, k, a: np.exp(3 * k - 2 + t) / a**2),
    ("+t - -k", lambda t, k, a: t + k),
    ("7", lambda t, k, a: np.full_like(t, 7.0)),
]


@pytest.mark.parametrize("text, formula", FORMULAS, ids=[f[0] for f in FORMULAS])
def test_separable_values_match_numpy(text, formula):
    p = points()
    assert np.allclose(separable(text).evaluate(**p), formula(p["t"], p["k"], p["a"]), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("text, formula", FORMULAS, ids=[f[0] for f in FORMULAS])
def test_text_of_a_separable_parses_back_to_the_same_values(text, formula):
    p = points(seed=1)
    sep = separable(text)
    again = separable(str(sep))
    assert np.allclose(again.evaluate(**p), sep.evaluate(**p), rtol=1e-12)


def test_evaluate_broadcasts_over_a_grid():
    sep = separable("k*exp(-t) + 3/(a*k)")
    t = np.linspace(0, 2, 5)[:, None, None]
    k = np.linspace(0.5, 5, 4)[None, :, None]
    a = np.linspace(0.2, 1, 3)[None, None, :]
    values = sep.evaluate(t=t, k=k, a=a)
    assert values.shape == (5, 4, 3)
    assert np.allclose(values, k * np.exp(-t) + 3 / (a * k))


def test_constant_evaluates_to_the_broadcast_shape():
    assert separable("2*g").evaluate(t=np.zeros(4)).shape == (4,)
    assert np.allclose(separable("2*g").evaluate(t=np.zeros(4)), 19.62)


def test_missing_coordinate_is_a_key_error():
    with pytest.raises(KeyError):
        separable("k*t").evaluate(t=np.ones(3))


def test_exp_of_a_sum_splits_into_one_factor_per_coordinate():
    sep = separable("exp(-k - 2*a)")
    assert len(sep.terms) == 1
    (term,) = sep.terms
    assert term.coef == 1.0
    assert [name for name, _ in term.factors] == ["a", "k"]
    factors = dict(term.factors)
    assert str(factors["k"]) == "exp(-k)"
    assert str(factors["a"]) == "exp(-2*a)"
    x = np.linspace(-1, 1, 7)
    assert np.allclose(factors["a"](x), np.exp(-2 * x))


def test_exp_of_a_sum_keeps_factors_that_would_overflow_or_cancel_in_the_joint():
    # exp(-(a - k*t)**2/w) split would have factors exp(-a**2/w), exp(2 a k t / w), ...: up to exp(400) on
    # this box, far larger than the whole (at most 1); with the domains known they stay in one joint factor
    text = "exp(-(a - k*t)**2/0.01)"
    domains = {"t": (0.0, 2.0), "k": (0.5, 5.0), "a": (0.2, 1.0)}
    kept = parse(text, domains=domains).coefficient(())
    assert not kept.terms and len(kept.joints) == 1
    assert kept.joints[0].function_text() == "exp(200*a*k*t + -100*k**2*t**2 - 100*a**2)"
    assert parse(text).coefficient(()).joints[0].function_text() == "exp(200*a*k*t + -100*k**2*t**2)*exp(-100*a**2)"
    p = points()
    np.testing.assert_allclose(kept.evaluate(**p), np.exp(-(p["a"] - p["k"] * p["t"]) ** 2 / 0.01), rtol=1e-12,
                               atol=1e-300)
    # small exponents over the box are still split off the joint
    small = parse("exp(-(a - k*t)**2/100)", domains=domains).coefficient(())
    assert small.joints[0].function_text() == "exp(0.02*a*k*t + -0.01*k**2*t**2)*exp(-0.01*a**2)"


def test_constant_part_of_an_exponent_becomes_the_coefficient():
    (term,) = separable("exp(1 + k - a)").terms
    assert term.coef == pytest.approx(np.e)
    assert [name for name, _ in term.factors] == ["a", "k"]


def test_sum_in_one_coordinate_stays_one_function():
    sep = separable("t**2 - 3*t + 1")
    func = merge_to_function(sep)
    assert func.coordinate == "t"
    x = np.linspace(0, 2, 9)
    assert np.allclose(func(x), x**2 - 3 * x + 1)
    assert merge_to_function(separable("k + t")) is None
    constant = merge_to_function(separable("2 + 3"))
    assert constant.coordinate is None and np.allclose(constant(np.zeros(3)), 5.0)


def test_quotient_in_one_coordinate_is_a_single_term():
    assert len(separable("(k + 1)/(k + 2)").terms) == 1
    assert len(separable("(k + a)*(k + 1)/k").terms) == 4
    assert separable("k/(2*k)") == Separable.constant(0.5)


def test_same_coordinate_factors_merge():
    (term,) = separable("k*k*exp(k)*a").terms
    assert [name for name, _ in term.factors] == ["a", "k"]
    x = np.linspace(0.5, 5, 6)
    assert np.allclose(dict(term.factors)["k"](x), x**2 * np.exp(x))


def test_like_terms_combine_and_zero_terms_vanish():
    assert len(separable("k*t + 2*t*k").terms) == 1
    assert separable("k*t - t*k").is_zero
    assert separable("k + t") == separable("t + k")
    assert hash(separable("k + t")) == hash(separable("t + k"))


def test_func1d_values_shapes_and_text():
    f = Func1D("t", ("call", "exp", ("neg", ("var",))))
    assert str(f) == "exp(-t)"
    assert f(np.zeros((2, 3))).shape == (2, 3)
    assert np.allclose(f(1.0), np.exp(-1.0))
    constant = Func1D(None, ("num", 2.5))
    assert np.array_equal(constant(np.zeros(4)), np.full(4, 2.5))
    x = np.arange(3.0)
    identity = Func1D("t")
    y = identity(x)
    y[0] = 99.0
    assert x[0] == 0.0  # the caller's array is not handed back
    assert hash(f) == hash(Func1D("t", ("call", "exp", ("neg", ("var",)))))


def test_separable_arithmetic():
    k, t = Separable.variable("k"), Separable.variable("t")
    expr = 2 * (k + 1) * t - t / 2 + (-k)
    p = points()
    assert np.allclose(expr.evaluate(**p), 2 * (p["k"] + 1) * p["t"] - p["t"] / 2 - p["k"])
    assert expr.coordinates == frozenset({"k", "t"})
    assert (1 - k).evaluate(k=np.array([3.0])) == pytest.approx(-2.0)
    assert str(separable("k*exp(-t) + 3/(a*k)")) == "k*exp(-t) + 3/(a*k)"


def test_septerm_rejects_repeated_or_mismatched_coordinates():
    with pytest.raises(ValueError):
        SepTerm(1.0, (("k", Func1D("k")), ("k", Func1D("k"))))
    with pytest.raises(ValueError):
        SepTerm(1.0, (("k", Func1D("t")),))


# ----------------------------------------------------------------------------------------------
# polynomials in the unknowns
# ----------------------------------------------------------------------------------------------
def test_linear_equation_monomials():
    poly = parse_equation("der(u) = -k*u + a*exp(-t)", **KW)
    der_u, u = (Atom("u", "t", 1),), (Atom("u"),)
    assert set(poly) == {(), u, der_u}
    assert poly.degree == 1
    assert poly.unknowns == frozenset({"u"})
    assert poly.atoms == frozenset({Atom("u"), Atom("u", "t", 1)})
    p = points()
    assert np.allclose(poly[der_u].evaluate(**p), 1.0)
    assert np.allclose(poly[u].evaluate(**p), p["k"])  # lhs - rhs: -(-k*u)
    assert np.allclose(poly.coefficient(()).evaluate(**p), -p["a"] * np.exp(-p["t"]))


def test_der_with_explicit_time_coordinate_is_der():
    assert parse("der(u, t)") == parse("der(u)")


def test_space_derivatives_only_when_allowed():
    assert "not supported" in error_of("der(u, k)")
    poly = parse("der(u, k) + der(v, a, 2)", allow_space_derivatives=True)
    assert poly.atoms == frozenset({Atom("u", "k", 1), Atom("v", "a", 2)})


def test_polynomial_degree_and_coefficients():
    poly = parse("(u + v)**2*k")
    assert poly.degree == 2
    uv = make_monomial(Atom("v"), Atom("u"))
    assert uv == (Atom("u"), Atom("v"))
    assert np.allclose(poly[uv].evaluate(k=np.array([1.5])), 3.0)
    assert set(poly) == {(Atom("u"), Atom("u")), uv, (Atom("v"), Atom("v"))}
    assert parse("der(u)*u").degree == 2
    assert parse("u**0") == Polynomial.constant(1.0)


def test_polynomial_arithmetic():
    u, v = Polynomial.atom(Atom("u")), Polynomial.atom(Atom("v"))
    expr = (u + 2) * (v - 1) - u * v
    assert expr == parse("-u + 2*v - 2")
    assert (-expr).degree == 1
    assert (expr * Separable.variable("k")).coefficient((Atom("v"),)) == Separable.variable("k") * 2
    assert (u - u).is_zero
    assert format_monomial((Atom("u"), Atom("u"), Atom("v", "t", 1)), time="t") == "u**2*der(v)"


# ----------------------------------------------------------------------------------------------
# constants
# ----------------------------------------------------------------------------------------------
def test_evaluate_constant():
    constants = {"g": 9.81}
    assert evaluate_constant(2, constants=constants, where="w") == 2.0
    assert evaluate_constant("1e-8", constants=constants, where="w") == 1e-8
    assert evaluate_constant("2*pi", constants=constants, where="w") == pytest.approx(2 * np.pi)
    assert evaluate_constant("g/2 + sqrt(4)", constants=constants, where="w") == pytest.approx(6.905)
    assert parse("g*k").coefficient(()) == separable("9.81*k")


@pytest.mark.parametrize(
    "value, fragment",
    [(True, "expected a number"), ([1], "expected a number"), ("h", "unknown name 'h'"), ("der(g)", "der() is not allowed"),
     (float("inf"), "finite"), ("1/0", "division by zero")],
)
def test_evaluate_constant_errors(value, fragment):
    with pytest.raises(ExpressionError, match="^c.yaml: constants.h: ") as info:
        evaluate_constant(value, constants={"g": 1.0}, where="c.yaml: constants.h")
    assert fragment in str(info.value)


# ----------------------------------------------------------------------------------------------
# errors
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "text, fragments",
    [
        ("exp(der(u))", ["der() may not appear inside the non-polynomial term 'exp(der(u))'"]),
        ("1/der(u)", ["der() may not appear inside the non-polynomial term '1/der(u)'"]),
        ("der(u)**0.5", ["non-polynomial term 'der(u)**0.5'", "integer powers"]),
        ("sin(u, v)", ["exactly one argument"]),
        ("exp(u % 2)", ["operator '%'"]),
        ("der(k)", ["der() may only wrap the name of an unknown", "unknowns: u, v"]),
        ("der(2*u)", ["der() may only wrap"]),
        ("der(u, t, 3)", ["order of a derivative must be 1 or 2"]),
        ("der(u, z)", ["second argument of der() must be a coordinate"]),
        ("1/0", ["division by zero in '1/0'"]),
        ("k/(t - t)", ["division by zero"]),
        ("10**400", ["overflows"]),
        ("exp(1000)", ["not a finite real number"]),
        ("1e999", ["too large"]),
        ("(-8)**(1/3)", ["not a real number"]),
        ("z*k", ["unknown name 'z' in 'z*k'", "coordinates: t, k, a", "constants: g", "unknowns: u, v"]),
        ("kk", ["did you mean 'k'?"]),
        ("sin", ["must be called"]),
        ("sin(t, k)", ["exactly one argument"]),
        ("k^2", ["'^'", "use ** for powers"]),
        ("k // 2", ["operator '//'"]),
        ("k == 1", ["comparison 'k == 1' is not allowed", "allowed are"]),
        ("u = 1", ["'=' is only allowed once, in equations"]),
        ("k +", ["invalid expression 'k +'"]),
        ("", ["empty"]),
        ("-" * 5000 + "1", ["invalid expression"]),
    ],
)
def test_error_messages(text, fragments):
    message = error_of(text)
    for fragment in fragments:
        assert fragment in message, message


def test_der_not_allowed_for_initial_values():
    assert "der() is not allowed here" in error_of("der(u)", allow_der=False)


def test_expansion_is_capped():
    names = [f"x{i}" for i in range(15)]
    text = "*".join(f"({n} + 1)" for n in names)  # 2**15 separated terms
    with pytest.raises(ExpressionError, match=f"at most {MAX_TERMS}"):
        parse_expression(text, coordinates=names, constants={}, unknowns=[], time=None, where="w")
    with pytest.raises(ExpressionError, match="too large to expand"):
        parse("u**2000")


def test_errors_are_spec_errors():
    assert issubclass(ExpressionError, SpecError)


@pytest.mark.parametrize(
    "text, fragment",
    [("der(u) == -u", "use a single '='"), ("der(u) = u = 1", "exactly one '='"), ("= u", "empty side"),
     ("der(u) - u", "exactly one '='")],
)
def test_equation_errors(text, fragment):
    with pytest.raises(ExpressionError, match="^" + re.escape(WHERE + ": ")) as info:
        parse_equation(text, **KW)
    assert fragment in str(info.value)


def test_equation_sides_are_subtracted():
    assert parse_equation("der(u) + k = 2*u", **KW) == parse("der(u) + k - 2*u")


def test_multiline_text_is_folded():
    assert parse("k\n + 1") == parse("k + 1")


# ----------------------------------------------------------------------------------------------
# safety: text is parsed, never executed
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "text",
    ["__import__('os')", "__import__('os').system('true')", "t.real", "lambda: 1", "().__class__", "[x for x in ()]",
     "open('f')", "eval('1')", "exec('1')", "k if t else a", "t[0]", "'abc'", "(x := 3)", "f'{t}'", "not t", "~t",
     "{1: 2}", "sin(*t)", "sin(x=t)", "np.sin(t)", "True", "None", "1j", "..."],
)
def test_anything_outside_the_whitelist_is_rejected(text):
    with pytest.raises(ExpressionError):
        parse(text)


def test_parsing_never_calls_eval_or_exec(monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("eval/exec called")

    monkeypatch.setattr(builtins, "eval", forbidden)
    monkeypatch.setattr(builtins, "exec", forbidden)
    assert parse_equation("der(u) = -k*u + sin(t)", **KW).degree == 1
    with pytest.raises(ExpressionError):
        parse("__import__('os').system('true')")


def test_package_sources_do_not_call_eval_exec_or_compile():
    folder = pathlib.Path(__file__).parents[2] / "pgdcli" / "problem"
    names = sorted(path.name for path in folder.glob("*.py"))
    assert {"expressions.py", "parser.py", "algebra.py", "trees.py", "general.py", "spec.py"} <= set(names)
    for name in names:
        source = (folder / name).read_text()
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
                assert node.func.id not in {"eval", "exec", "compile", "__import__"}, (name, node.func.id)


# ----------------------------------------------------------------------------------------------
# property: random separable expressions built as (text, numpy function) pairs
# ----------------------------------------------------------------------------------------------
COORDS = ("t", "k", "a")


def _leaf():
    coordinate = st.sampled_from(COORDS).map(lambda c: (c, lambda p, c=c: p[c], frozenset({c})))
    number = st.integers(1, 5).map(lambda n: (str(n), lambda p, n=n: float(n), frozenset()))
    return coordinate | number


def _extend(children):
    def combine(pair, op):
        (ta, fa, ca), (tb, fb, cb) = pair
        if op == "+":
            return (f"({ta} + {tb})", lambda p: fa(p) + fb(p), ca | cb)
        if op == "-":
            return (f"({ta} - {tb})", lambda p: fa(p) - fb(p), ca | cb)
        return (f"({ta})*({tb})", lambda p: fa(p) * fb(p), ca | cb)

    def apply(item, fname):
        text, f, coords = item
        if len(coords) > 1:
            return item
        if fname == "exp":
            return (f"exp({text}/10)", lambda p: np.exp(f(p) / 10), coords)
        if fname == "div":  # a positive one-coordinate denominator
            return (f"1/(1 + ({text})**2)", lambda p: 1 / (1 + f(p) ** 2), coords)
        return (f"sin({text})", lambda p: np.sin(f(p)), coords)

    binary = st.tuples(st.tuples(children, children), st.sampled_from("+-*")).map(lambda x: combine(*x))
    unary = st.tuples(children, st.sampled_from(["exp", "div", "sin"])).map(lambda x: apply(*x))
    return binary | unary


@settings(max_examples=60, deadline=None)
@given(st.recursive(_leaf(), _extend, max_leaves=8))
def test_random_separable_expressions_match_numpy(item):
    text, formula, _ = item
    p = points(20, seed=3)
    sep = separable(text)
    assert np.allclose(sep.evaluate(**p), formula(p), rtol=1e-9, atol=1e-9)
