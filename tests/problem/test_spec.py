"""Tests of pgdcli.problem.spec: YAML problem specification -> validated Problem."""

from __future__ import annotations

import dataclasses
import pathlib
import re
import textwrap

import numpy as np
import pytest

from conftest import spec_text
from pgdcli.errors import ExpressionError, SpecError
from pgdcli.problem.expressions import Atom
from pgdcli.problem.spec import Coordinate, Equation, Problem, SolverOptions, check_linear, load_spec, parse_spec

SOURCE = "problems/x.yaml"

FULL = textwrap.dedent(
    """\
    name: relaxation
    description: |
      First-order relaxation
    coordinates:
      t: {domain: [0, 2], nodes: 32}
      k: {domain: [0.5, 5], nodes: 24}
      a: {domain: [-1, 1], nodes: 8, discretization: linear}
    time: t
    constants: {g: 9.81, half_g: "g/2", eps: 1e-8, two_pi: 2*pi}
    unknowns:
      u: {initial: a}
      v: {initial: "0.5*exp(-k)"}
    equations:
      - "der(u) = -k*u + v + half_g"
      - der(v) = -v
    solver: {tolerance: 1e-6, max_modes: 40, formulation: galerkin, fixed_point_tolerance: "1e-7",
             max_fixed_point_iterations: 12, update: false}
    output: out/relax.h5
    """
)

MINIMAL = spec_text()  # the shared factory's minimal spec (tests/conftest.py)
spec = spec_text  # the minimal spec with some top-level sections replaced, added or removed (None)


def error_of(text: str, **kwargs) -> str:
    with pytest.raises(SpecError) as info:
        parse_spec(text, source=SOURCE, **kwargs)
    message = str(info.value)
    assert "\n" not in message
    return message


# ----------------------------------------------------------------------------------------------
# valid specs
# ----------------------------------------------------------------------------------------------
def test_full_spec():
    problem = parse_spec(FULL, source=SOURCE)
    assert problem.name == "relaxation"
    assert problem.description == "First-order relaxation"
    assert problem.coordinates == (
        Coordinate("t", (0.0, 2.0), 32, "chebyshev", "time"),
        Coordinate("k", (0.5, 5.0), 24, "chebyshev", "parameter"),
        Coordinate("a", (-1.0, 1.0), 8, "linear", "parameter"),
    )
    assert problem.time == "t"
    assert problem.constants == pytest.approx({"g": 9.81, "half_g": 4.905, "eps": 1e-8, "two_pi": 2 * np.pi})
    assert problem.unknown_names == ("u", "v")
    assert problem.solver == SolverOptions(1e-6, max_modes=40, formulation="galerkin", fixed_point_tolerance=1e-7,
                                           max_fixed_point_iterations=12, update=False)
    assert problem.output == pathlib.Path("out/relax.h5")
    assert problem.source == SOURCE and problem.source_text == FULL
    assert problem.coordinate_names == ("t", "k", "a")
    assert problem.time_coordinate.name == "t"
    assert [c.name for c in problem.parameter_coordinates] == ["k", "a"]
    assert problem.coordinate("k").nodes == 24
    with pytest.raises(KeyError):
        problem.coordinate("z")


def test_initial_values_are_separable_functions():
    problem = parse_spec(FULL)
    u, v = problem.unknowns
    k = np.linspace(0.5, 5, 7)
    a = np.linspace(-1, 1, 7)
    assert u.initial_text == "a" and np.allclose(u.initial.evaluate(a=a), a)
    assert v.initial_text == "0.5*exp(-k)" and np.allclose(v.initial.evaluate(k=k), 0.5 * np.exp(-k))


def test_equations_are_linear_polynomials():
    problem = parse_spec(FULL)
    first, second = problem.equations
    assert (first.index, first.text) == (0, "der(u) = -k*u + v + half_g")
    poly = first.polynomial
    assert set(poly) == {(), (Atom("u"),), (Atom("v"),), (Atom("u", "t", 1),)}
    k = np.linspace(0.5, 5, 5)
    assert np.allclose(poly[(Atom("u"),)].evaluate(k=k), k)
    assert np.allclose(poly[(Atom("v"),)].evaluate(k=k), -1.0)
    assert np.allclose(poly.coefficient(()).evaluate(k=k), -4.905)
    assert second.polynomial.degree == 1


def test_defaults():
    problem = parse_spec(MINIMAL)
    assert problem.name == "problem"
    assert problem.description == ""
    assert problem.time == "t"
    assert problem.constants == {}
    assert problem.solver == SolverOptions()
    assert problem.output == pathlib.Path("codebooks/problem.h5")
    assert problem.coordinates[0].discretization == "chebyshev"
    assert problem.unknowns[0].initial.is_zero
    assert parse_spec(MINIMAL, name="given").name == "given"
    assert parse_spec("name: own\n" + MINIMAL, name="given").name == "own"


def test_load_spec_uses_the_file_stem(tmp_path):
    path = tmp_path / "decay-1.yaml"
    path.write_text(MINIMAL)
    problem = load_spec(path)
    assert problem.name == "decay-1"
    assert problem.source == str(path)
    assert problem.output == pathlib.Path("codebooks/decay-1.h5")


def test_load_spec_errors_name_the_path(tmp_path):
    missing = tmp_path / "missing.yaml"
    with pytest.raises(SpecError, match=re.escape(f"{missing}: cannot read problem file")):
        load_spec(missing)
    with pytest.raises(SpecError, match="directory"):
        load_spec(tmp_path)
    bad = tmp_path / "bad.yaml"
    bad.write_text(MINIMAL.replace("nodes: 4", "nodes: 1"))
    with pytest.raises(SpecError, match=re.escape(f"{bad}: coordinates.t.nodes: ")):
        load_spec(bad)


def test_numeric_strings_are_numbers():
    # PyYAML reads 1e-8 (no dot) as a string
    problem = parse_spec(spec(coordinates="\n  t: {domain: [1e-3, 2e0], nodes: '16'}", solver=" {tolerance: 1e-9}"))
    assert problem.coordinates[0].domain == (1e-3, 2.0)
    assert problem.coordinates[0].nodes == 16
    assert problem.solver.tolerance == 1e-9


def test_domain_may_use_pi_and_constants():
    problem = parse_spec(spec(constants=" {T: 3}", coordinates="\n  t: {domain: [0, 2*pi*T], nodes: 4}"))
    assert problem.coordinates[0].domain == pytest.approx((0.0, 6 * np.pi))


def test_custom_time_coordinate():
    problem = parse_spec(spec(coordinates="\n  x: {domain: [0, 1], nodes: 4}\n  s: {domain: [0, 1], nodes: 4}", time=" s",
                              equations="\n  - der(u) = -x*u"))
    assert problem.time == "s"
    assert [c.role for c in problem.coordinates] == ["parameter", "time"]


def test_problem_is_frozen():
    problem = parse_spec(MINIMAL)
    with pytest.raises(dataclasses.FrozenInstanceError):
        problem.name = "other"


# ----------------------------------------------------------------------------------------------
# linearity
# ----------------------------------------------------------------------------------------------
NONLINEAR = spec(unknowns="\n  u: {initial: 0}\n  v: {initial: 1}", equations="\n  - der(u) = -u*v\n  - der(v) = u")


def test_nonlinear_term_is_rejected_when_linear_is_required():
    with pytest.raises(SpecError) as info:
        parse_spec(NONLINEAR, source=SOURCE, allow_nonlinear=False)
    assert str(info.value) == (
        f"{SOURCE}: equations[0]: nonlinear term 'u*v' in 'der(u) = -u*v';"
        " only equations linear in the unknowns are supported"
    )


def test_derivative_times_unknown_is_always_rejected():
    message = error_of(spec(equations="\n  - der(u)*u = 1"))
    assert message.startswith(f"{SOURCE}: equations[0]: term ")
    assert "der(u)" in message and "must appear linearly" in message


def test_allow_nonlinear_accepts_degree_two():
    problem = parse_spec(NONLINEAR, allow_nonlinear=True)
    assert [eq.polynomial.degree for eq in problem.equations] == [2, 1]
    with pytest.raises(SpecError, match="nonlinear term 'u\\*v'"):
        check_linear(problem)
    with pytest.raises(SpecError, match="^src: equations\\[0\\]: nonlinear"):
        check_linear(list(problem.equations), source="src")
    check_linear([Equation(0, "der(u) = -u", parse_spec(MINIMAL).equations[0].polynomial)])


# ----------------------------------------------------------------------------------------------
# YAML-level errors
# ----------------------------------------------------------------------------------------------
def test_duplicate_keys_are_rejected():
    text = spec(coordinates="\n  t: {domain: [0, 1], nodes: 4}\n  t: {domain: [0, 2], nodes: 4}")
    assert error_of(text) == f"{SOURCE}: line 3, column 3: invalid YAML: duplicate key 't' (first defined at line 2)"
    assert "duplicate key 'nodes'" in error_of(spec(coordinates="\n  t: {domain: [0, 1], nodes: 4, nodes: 5}"))


def test_yaml_syntax_error_is_one_line_with_line_number():
    assert re.match(rf"^{re.escape(SOURCE)}: line 3, column \d+: invalid YAML: ", error_of("coordinates:\n  t: [0, 1\nunknowns: 3\n"))


@pytest.mark.parametrize(
    "text, expected",
    [
        ("", "expected a YAML mapping"),
        ("- 1\n- 2\n", "expected a YAML mapping"),
        ("!!python/object:os.system {}\n", "invalid YAML"),
    ],
)
def test_document_must_be_a_mapping(text, expected):
    assert error_of(text).startswith(f"{SOURCE}: ")
    assert expected in error_of(text)


def test_boolean_names_must_be_quoted():
    message = error_of(spec(coordinates="\n  t: {domain: [0, 1], nodes: 4}\n  on: {domain: [0, 1], nodes: 4}"))
    assert message.startswith(f"{SOURCE}: coordinates: name true is a YAML boolean")
    assert "quote" in message
    assert parse_spec(spec(coordinates="\n  t: {domain: [0, 1], nodes: 4}\n  'on': {domain: [0, 1], nodes: 4}"))
    assert error_of(spec(time=" yes")).startswith(f"{SOURCE}: time: got the YAML boolean true; quote")


# ----------------------------------------------------------------------------------------------
# key-path errors
# ----------------------------------------------------------------------------------------------
C2 = "\n  t: {domain: [0, 1], nodes: 4}\n  k: "


@pytest.mark.parametrize(
    "sections, expected",
    [
        # top level
        (dict(foo=" 1"), "unknown key 'foo' (allowed: name, description, coordinates, time, constants, unknowns,"),
        (dict(coordinates=None), "missing required key 'coordinates'"),
        (dict(name=" 'my problem'"), "name: expected letters, digits"),
        (dict(name=" 12"), "name: expected a string"),
        (dict(description=" [1]"), "description: expected a string, got [1]"),
        # coordinates
        (dict(coordinates=" {}"), "coordinates: expected a non-empty mapping"),
        (dict(coordinates=" [t]"), "coordinates: expected a mapping, got ['t']"),
        (dict(coordinates=C2 + "{domain: [5, 1], nodes: 4}"),
         "coordinates.k.domain: expected [low, high] with low < high, got [5, 1]"),
        (dict(coordinates=C2 + "{domain: [1], nodes: 4}"), "coordinates.k.domain: expected [low, high], got [1]"),
        (dict(coordinates=C2 + "{domain: [0, .inf], nodes: 4}"), "coordinates.k.domain: expected a finite number"),
        (dict(coordinates=C2 + "{domain: [0, abc], nodes: 4}"), "coordinates.k.domain: unknown name 'abc'"),
        (dict(coordinates=C2 + "{domain: [0, true], nodes: 4}"), "coordinates.k.domain: expected a number, got true"),
        (dict(coordinates=C2 + "{nodes: 4}"), "coordinates.k: missing required key 'domain'"),
        (dict(coordinates=C2 + "{domain: [0, 1], nodes: 3.5}"), "coordinates.k.nodes: expected 'auto' or an integer in [2, 2000], got 3.5"),
        (dict(coordinates=C2 + "{domain: [0, 1], nodes: true}"), "coordinates.k.nodes: expected 'auto' or an integer in [2, 2000], got true"),
        (dict(coordinates=C2 + "{domain: [0, 1], nodes: 1}"), "coordinates.k.nodes: expected 'auto' or an integer in [2, 2000], got 1"),
        (dict(coordinates=C2 + "{domain: [0, 1], nodes: 2001}"), "coordinates.k.nodes: expected 'auto' or an integer in [2, 2000]"),
        (dict(coordinates=C2 + "{domain: [0, 1], nodes: many}"), "coordinates.k.nodes: expected 'auto' or an integer"),
        (dict(coordinates=C2 + "{domain: [0, 1], nodes: 4, discretization: spline}"),
         "coordinates.k.discretization: expected one of chebyshev, linear, got 'spline'"),
        (dict(coordinates=C2 + "{domain: [0, 1], nodes: 4, size: 3}"),
         "coordinates.k: unknown key 'size' (allowed: domain, nodes, discretization, elements)"),
        (dict(coordinates=C2 + "5"), "coordinates.k: expected a mapping, got 5"),
        # names
        (dict(coordinates="\n  t: {domain: [0, 1], nodes: 4}\n  sin: {domain: [0, 1], nodes: 4}"), "coordinates.sin: 'sin' is reserved"),
        (dict(coordinates="\n  t: {domain: [0, 1], nodes: 4}\n  seed: {domain: [0, 1], nodes: 4}"), "coordinates.seed: 'seed' is reserved"),
        (dict(coordinates="\n  t: {domain: [0, 1], nodes: 4}\n  lambda: {domain: [0, 1], nodes: 4}"), "coordinates.lambda: 'lambda' is a Python keyword"),
        (dict(coordinates="\n  t: {domain: [0, 1], nodes: 4}\n  2k: {domain: [0, 1], nodes: 4}"), "coordinates.2k: invalid name '2k'"),
        (dict(coordinates="\n  t: {domain: [0, 1], nodes: 4}\n  3: {domain: [0, 1], nodes: 4}"), "coordinates: expected a name, got 3"),
        (dict(constants=" {t: 1}"), "constants.t: name 't' is already used by coordinates.t"),
        (dict(constants=" {pi: 3}"), "constants.pi: 'pi' is reserved"),
        (dict(unknowns="\n  t: {initial: 0}"), "unknowns.t: name 't' is already used by coordinates.t"),
        # constants
        (dict(constants=" {g: [1]}"), "constants.g: expected a number or an expression string, got [1]"),
        (dict(constants=" {g: h, h: 1}"), "constants.g: unknown name 'h'"),
        (dict(constants=" {g: t}"), "constants.g: unknown name 't'"),
        (dict(constants=" {g: 1/0}"), "constants.g: division by zero"),
        # time
        (dict(coordinates="\n  x: {domain: [0, 1], nodes: 4}"), "time: no coordinate is named 't'"),
        (dict(time=" s"), "time: expected the name of a coordinate (t) or null (steady), got 's'"),
        # unknowns
        (dict(unknowns=" {}"), "unknowns: expected a non-empty mapping"),
        (dict(unknowns="\n  u: 0"), "unknowns.u: expected a mapping with key 'initial'"),
        (dict(unknowns="\n  u: {}"), "unknowns.u: missing required key 'initial'"),
        (dict(unknowns="\n  u: {initial: 0, value: 1}"), "unknowns.u: unknown key 'value' (allowed: initial, boundary)"),
        (dict(unknowns="\n  u: {initial: t}"), "unknowns.u.initial: the initial value of 'u' must not depend on the time coordinate 't'"),
        (dict(unknowns="\n  u: {initial: 2*u}"), "unknowns.u.initial: the initial value of 'u' must not depend on unknowns"),
        (dict(unknowns="\n  u: {initial: der(u)}"), "unknowns.u.initial: der() is not allowed here"),
        (dict(unknowns="\n  u: {initial: [0]}"), "unknowns.u.initial: expected a number or an expression string"),
        (dict(unknowns="\n  u: {initial: z}"), "unknowns.u.initial: unknown name 'z'"),
        # equations
        (dict(equations=" der(u) = -u"), "equations: expected a list of equation strings"),
        (dict(equations="\n  - der(u) = -u\n  - der(u) = 1"), "equations: expected 1 equation(s), one per unknown (u), got 2"),
        (dict(equations="\n  - 3"), "equations[0]: expected an equation string like 'der(u) = -u', got 3"),
        (dict(equations="\n  - der(u): -u"), "equations[0]: expected an equation string, got a mapping"),
        (dict(equations="\n  - der(u) = sin(k*t)*u"), "equations[0]: unknown name 'k'"),
        (dict(equations="\n  - der(u) = 1/der(u)"), "equations[0]: der() may not appear inside the non-polynomial term '1/der(u)'"),
        (dict(equations="\n  - der(u) = __import__('os')"), "equations[0]: call '__import__('os')' in 'der(u) = __import__('os')' is not allowed"),
        (dict(equations="\n  - u = 1"), "equations[0]: no time derivative in 'u = 1'"),
        (dict(equations="\n  - der(u, t, 2) = -u"), "equations[0]: der(u, t, 2) needs the initial rate of 'u': write its initial condition as {value: <x0>, rate: <v0>}"),
        (dict(unknowns="\n  u: {initial: 0}\n  v: {initial: 0}", equations="\n  - der(u) = v\n  - der(u) = u"),
         "equations: unknown 'v' never appears as der(v)"),
        # solver
        (dict(solver=" {tolerance: 2}"), "solver.tolerance: expected a number in (0, 1), got 2"),
        (dict(solver=" {tolerance: small}"), "solver.tolerance: expected a number, got 'small'"),
        (dict(solver=" {fixed_point_tolerance: 0}"), "solver.fixed_point_tolerance: expected a number in (0, 1), got 0"),
        (dict(solver=" {max_modes: 0}"), "solver.max_modes: expected an integer >= 1, got 0"),
        (dict(solver=" {max_fixed_point_iterations: 2.5}"), "solver.max_fixed_point_iterations: expected an integer >= 1, got 2.5"),
        (dict(solver=" {formulation: ritz}"), "solver.formulation: expected one of minres, galerkin, got 'ritz'"),
        (dict(solver=" {update: maybe}"), "solver.update: expected true or false, got 'maybe'"),
        (dict(solver=" {march: tensor}"), "solver.march: expected one of auto, grid, cross, train, got 'tensor'"),
        (dict(solver=" {integrator: rk4}"), "solver.integrator: expected one of auto, dop853, bs32, rodas4, got 'rk4'"),
        (dict(solver=" {restarts: 3}"), "solver: unknown key 'restarts' (allowed: tolerance, relative_tolerance, max_nodes, max_modes,"),
        (dict(solver=" 3"), "solver: expected a mapping, got 3"),
        # output
        (dict(output=" ''"), "output: expected a non-empty file path, got ''"),
        (dict(output=" [a]"), "output: expected a non-empty file path"),
    ],
)
def test_error_names_the_key_path(sections, expected):
    message = error_of(spec(**sections))
    assert message.startswith(f"{SOURCE}: {expected}"), message


def test_expression_errors_are_spec_errors_with_the_source():
    with pytest.raises(ExpressionError, match=re.escape(f"{SOURCE}: equations[0]: ")):
        parse_spec(spec(equations="\n  - der(u) = der(u)**0.5"), source=SOURCE)


def test_default_name_from_an_invalid_file_name(tmp_path):
    path = tmp_path / "my problem.yaml"
    path.write_text(MINIMAL)
    with pytest.raises(SpecError, match="name: the default name 'my problem'"):
        load_spec(path)
    path.write_text("name: mine\n" + MINIMAL)
    assert load_spec(path).name == "mine"


def test_problem_is_hashable_and_comparable():
    assert parse_spec(MINIMAL) == parse_spec(MINIMAL)
    assert isinstance(hash(parse_spec(MINIMAL)), int)
    assert isinstance(parse_spec(MINIMAL), Problem)


def test_every_shipped_problem_parses_and_is_checked_by_a_test():
    tests = "".join(p.read_text() for p in pathlib.Path("tests").rglob("test_*.py"))
    shipped = sorted(pathlib.Path("problems").glob("*.yaml"))
    assert shipped
    for path in shipped:
        problem = load_spec(path)
        assert problem.name == path.stem
        assert f"problems/{path.name}" in tests or f'"{path.stem}"' in tests, f"no test solves {path}"
