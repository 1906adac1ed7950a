"""What the PDE march takes (pgdcli.algorithms.pde_structure): the parts of a reaction-diffusion system,
and one line naming the key and the reason for each form it refuses."""

import pytest

from pgdcli.algorithms.pde_structure import pde_refusal, pde_structure
from pgdcli.algorithms.pde_system import compile_pde_system
from pgdcli.discretization.basis import make_basis
from pgdcli.errors import SolverError
from pgdcli.problem.spec import parse_spec

GRAY_SCOTT = """
coordinates:
  t: {domain: [0, 1]}
  x: {domain: [0, 1]}
  y: {domain: [0, 1]}
  F: {domain: [0.02, 0.05]}
  d: {domain: [1, 2]}
unknowns:
  u:
    initial: "1 - 0.5*cos(pi*x)*cos(pi*y)"
    boundary:
      x: {low: {gradient: 0}, high: {gradient: 0}}
      y: {low: {gradient: 0}, high: {gradient: 0}}
  v:
    initial: "0.25*cos(pi*x)*cos(pi*y)"
    boundary:
      x: {low: {gradient: 0}, high: {gradient: 0}}
      y: {low: {gradient: 0}, high: {gradient: 0}}
equations:
  - "der(u) = 0.02*(der(u, x, 2) + der(u, y, 2)) - u*v**2 + F*(1 - u)"
  - "2*der(v) = 0.01*d*(der(v, x, 2) + der(v, y, 2)) + u*v**2 - (F + 0.06)*v"
"""


def test_the_structure_of_a_two_species_system_in_two_space_coordinates():
    s = pde_structure(parse_spec(GRAY_SCOTT, source="gs.yaml"))
    assert s.space == ("x", "y") and s.species == ("u", "v")
    assert s.params == ("d", "F")  # the diffusion's parameter first: the march's merged modes
    assert s.diffusion_params == ["d"] and s.modes == ["x", "y", "d", "F"]
    assert [str(c) for c in s.diffusion[0]] == ["0.02", "0.02"]
    assert s.mass[1].constant_value == 2.0 and len(s.terms[0]) == 3  # u*v**2, F, F*u


@pytest.mark.parametrize("edit, where, reason", [
    (("  F: {domain: [0.02, 0.05]}", "  F: {domain: [0.02, 0.05]}\n  z: {domain: [0, 1]}"),
     "coordinates", "3 space coordinates (x, y, z); at most 2"),
    (("+ u*v**2 - (F", "+ u*v**2 + 0.001*der(u, x, 2) - (F"), "equations[1]", "cross-diffusion der(u, x, 2)"),
    (("0.02*(der(u, x, 2) + der(u, y, 2))", "0.02*der(u, x, 2)"), "equations[0]", "no diffusion term c*der(u, y, 2)"),
    (("0.01*d*(der(v, x, 2)", "0.01*(d - 1.5)*(der(v, x, 2)"), "equations[1]",
     "the diffusion coefficient of v along x, 0.01*d - 0.015, is -0.005 at d=1: it must be positive"),
    (("0.01*d*(der(v, x, 2)", "0.01*x*(der(v, x, 2)"), "equations[1]",
     "the diffusion coefficient of v along x must not depend on x"),
    (("2*der(v)", "(F - 0.03)*der(v)"), "equations[1]",
     "the coefficient of der(v), F - 0.03, changes sign (-0.01 at F=0.02, 0.02 at F=0.05): it must not vanish"),
    (("- u*v**2 + F*(1 - u)", "- u*v**2 + F*(1 - u) + der(u)*v"), "equations[0]",
     "der(u) must appear alone and linearly"),
])
def test_forms_the_march_refuses_in_one_line(edit, where, reason):
    text = GRAY_SCOTT.replace(*edit)
    if "z: {domain" in text:  # a third space coordinate: its conditions and diffusion too
        text = text.replace("      y: {low: {gradient: 0}, high: {gradient: 0}}\n",
                            "      y: {low: {gradient: 0}, high: {gradient: 0}}\n"
                            "      z: {low: {gradient: 0}, high: {gradient: 0}}\n")
        text = text.replace("der(u, y, 2))", "der(u, y, 2) + der(u, z, 2))")
    try:
        problem = parse_spec(text, source="gs.yaml")
    except Exception as exc:  # the spec layer refuses some forms first: still one line naming the key
        assert where in str(exc) and "\n" not in str(exc), exc
        return
    refusal = pde_refusal(problem)
    assert refusal is not None and "\n" not in refusal
    assert refusal.startswith(f"gs.yaml: {where}: ") and reason in refusal, refusal


def test_a_second_order_nonlinear_pde_is_refused_naming_its_rate():
    """Sine-Gordon written with der(u, t, 2): one unknown for the user, so the refusal says where the second
    comes from instead of '2 unknowns'."""
    text = """
coordinates:
  t: {domain: [0, 1]}
  x: {domain: [0, 1]}
unknowns:
  u: {initial: {value: "sin(pi*x)", rate: 0}, boundary: {x: {low: 0, high: 0}}}
equations:
  - "der(u, t, 2) = der(u, x, 2) - u**3"
"""
    reason = pde_refusal(parse_spec(text, source="sg.yaml"))
    assert "der(u, t, 2) makes a system of u and its rate u_rate" in reason and "2 unknowns" not in reason


def test_boundary_data_that_disagree_at_a_corner_are_refused():
    """u = 1 on x = 0 but u = 0 on y = 0: the corner (0, 0) asks two values."""
    text = GRAY_SCOTT.replace("      x: {low: {gradient: 0}, high: {gradient: 0}}\n      y: {low: {gradient: 0}, "
                              "high: {gradient: 0}}\n  v:", "      x: {low: 1, high: {gradient: 0}}\n      y: {low: 0, "
                              "high: {gradient: 0}}\n  v:", 1)
    problem = parse_spec(text, source="gs.yaml")
    message = ("gs.yaml: unknowns.u.boundary: the conditions on x (low) and on y (low) disagree at the corner x=0, "
               "y=0 by 1 ")
    assert pde_refusal(problem).startswith(message)  # before solving
    bases = {c.name: make_basis("chebyshev", c.domain, 9) for c in problem.coordinates if c.name != "t"}
    with pytest.raises(SolverError) as caught:
        compile_pde_system(problem, bases, corner_tolerance=1e-6)
    assert str(caught.value).startswith(message)
