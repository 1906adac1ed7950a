"""An initial value that misses a Dirichlet value is refused before any solve, naming both keys."""

from __future__ import annotations

import subprocess
import sys

import pytest

from pgdcli import parse_spec
from pgdcli.errors import SolverError, SpecError
from pgdcli.problem.compatibility import check_initial_meets_boundary
from conftest import spec_text

FRONT = spec_text(
    None,
    name=" front",
    coordinates={"t": "{domain: [0, 1]}", "x": "{domain: [0, 1]}", "D": "{domain: [0.01, 0.05]}",
                 "k": "{domain: [2, 6]}"},
    unknowns='\n  u:\n    initial: "0.5*(1 - tanh(10*(x - 0.3)))"\n    boundary:\n      x: {low: 1, high: 0}',
    equations=['"der(u) = D*der(u, x, 2) + k*u**2*(1 - u)"'],
    solver=" {tolerance: 1e-6}",
)


def test_a_front_that_misses_its_boundary_value_exits_2_in_one_line(tmp_path):
    """Without -q too: the refusal comes before the progress bar, so it is the only line on stderr."""
    spec = tmp_path / "front.yaml"
    spec.write_text(FRONT)
    out = tmp_path / "front.h5"
    run = subprocess.run([sys.executable, "-c", "from pgdcli.cli.entry import main; main()", "solve", str(spec),
                          "-o", str(out)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and not out.exists() and run.stdout == ""
    assert run.stderr == (f"Error: {spec}: unknowns.u.initial is 0.9975273768 at x=0 but unknowns.u.boundary.x.low "
                          f"is 1: they differ by 0.0025, more than 1e-06, which puts a layer at t = 0 that no "
                          f"codebook resolves; make the initial value meet the boundary value there\n")


def test_the_gap_is_found_where_a_parameter_makes_it_largest():
    text = FRONT.replace('"0.5*(1 - tanh(10*(x - 0.3)))"', '"(1 + 0.001*(D - 0.01))*(1 - x)"')
    with pytest.raises(SpecError, match=r"initial is 1.00004 at x=0, D=0.05 but .*boundary.x.low is 1: they "
                                        r"differ by 4e-05"):
        check_initial_meets_boundary(parse_spec(text, source="front.yaml"), 1e-6)
    check_initial_meets_boundary(parse_spec(text, source="front.yaml"), 1e-4)  # within the tolerance: no error


def test_the_relative_tolerance_counts_and_the_error_type_is_the_callers():
    text = FRONT.replace('"0.5*(1 - tanh(10*(x - 0.3)))"', '"1.00001*(1 - x)"')
    problem = parse_spec(text, source="front.yaml")
    check_initial_meets_boundary(problem, 1e-6, 1e-4)  # 1e-5 <= 1e-6 + 1e-4 * 1
    with pytest.raises(SolverError, match="more than 1e-09, and the lift"):
        check_initial_meets_boundary(problem, 1e-9, 0.0, why="and the lift", error=SolverError)


def test_gradient_conditions_and_problems_without_space_pass():
    neumann = FRONT.replace("x: {low: 1, high: 0}", "x: {low: {gradient: 0}, high: {gradient: 0}}")
    check_initial_meets_boundary(parse_spec(neumann, source="n.yaml"), 1e-6)
    check_initial_meets_boundary(parse_spec(spec_text(), source="ode.yaml"), 1e-6)


@pytest.mark.parametrize("initial, message", [
    ("exp(1000*x)", "unknowns.u.initial is inf at x=1: an initial value must be finite"),
    ("(1 - x)*sqrt(D - 0.02)", "unknowns.u.initial is nan at D=0.01, x=0: an initial value must be finite"),
    ("(1 - x)/(k - 4)", "unknowns.u.initial is nan at k=4, x=0.5: an initial value must be finite"),  # inf - inf
])
def test_an_initial_value_that_is_not_finite_is_refused_before_solving(initial, message):
    from pgdcli.driver import check_solvable

    text = FRONT.replace('"0.5*(1 - tanh(10*(x - 0.3)))"', f'"{initial}"')
    with pytest.raises(SpecError, match=message.replace("(", r"\(").replace(")", r"\)")):
        check_solvable(parse_spec(text, source="front.yaml"), 1e-6, 0.0, 100)


def test_a_coefficient_that_is_not_finite_is_refused_naming_its_equation():
    from pgdcli.driver import check_solvable

    text = spec_text(None, name=" pole", coordinates={"t": "{domain: [0, 1]}", "a": "{domain: [-1, 1]}"},
                     unknowns={"u": "{initial: 1}"}, equations=['"der(u) = -u**2/a + log(2 + t)"'])
    with pytest.raises(SpecError, match=r"pole.yaml: equations\[0\]: the coefficient 1/a is inf at a=0: "
                                        r"coefficients must be finite"):
        check_solvable(parse_spec(text, source="pole.yaml"), 1e-6, 0.0, 100)
    fine = text.replace("[-1, 1]", "[0.5, 1]")
    check_solvable(parse_spec(fine, source="pole.yaml"), 1e-6, 0.0, 100)
