"""Reaction-diffusion systems and two space coordinates through pgdcli.solve / pgd solve / pgd verify.

The shipped problems (problems/brusselator_pde.yaml: two species, a rate as coordinate, boundary values
depending on it; problems/allen_cahn2d.yaml: two space coordinates) solve from their specs without node
counts, and each codebook is measured here against the independent nonlinear method of lines
(pgdcli.checks.reference_pde_nonlinear: its own Chebyshev collocation and boundary elimination, Radau,
grids refined until two agree; itself checked against exact solutions in
tests/checks/test_reference_pde_nonlinear.py) at 300 random points (3 parameter samples x 5 times x 20
space points) and on the faces and corners of the box: the parameters' ends, the start and end time, the
space coordinates' ends and corners, in every combination with the random values of the others.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pgdcli
from pgdcli.checks.reference_pde_nonlinear import solve_reference_nonlinear_pde

from cli_refusal import assert_refused_in_one_line

ROOT = Path(__file__).resolve().parents[2]


def _space_points(space, rng) -> np.ndarray:
    """20 random points, 4 on each face, and the corners of the space box: (P, d)."""
    domains = np.array([c.domain for c in space])
    lo, hi = domains[:, 0], domains[:, 1]
    points = [rng.uniform(lo, hi, (20, len(space)))]
    for a in range(len(space)):
        for end in (lo[a], hi[a]):
            face = rng.uniform(lo, hi, (4, len(space)))
            face[:, a] = end
            points.append(face)
    corners = np.stack(np.meshgrid(*domains, indexing="ij"), axis=-1).reshape(-1, len(space))
    return np.vstack(points + [corners])


def worst_errors(problem, cb, seed: int = 32) -> dict:
    """Max abs error per unknown at random, face and corner points against the nonlinear method of lines.

    Parameter samples: 3 random and every corner of the parameter box (the gate's corners: its reference
    solutions are reused); times: 5 random and both ends;
    space: :func:`_space_points`; every combination of the three (the 300 random points among them).
    """
    rng = np.random.default_rng(seed)
    params = [c for c in problem.coordinates if c.role == "parameter"]
    space = [c for c in problem.coordinates if c.role == "space"]
    t = problem.time_coordinate
    corners = np.stack(np.meshgrid(*[c.domain for c in params], indexing="ij"), axis=-1).reshape(-1, len(params))
    random = np.stack([rng.uniform(*c.domain, 3) for c in params], axis=1)
    samples = np.vstack([random, corners])
    times = np.concatenate([np.sort(rng.uniform(*t.domain, 5)), t.domain])
    points = _space_points(space, rng)
    tolerance = problem.solver.tolerance
    # an error estimate within a thousandth of the tolerance (the default)
    ref = solve_reference_nonlinear_pde(problem, {c.name: samples[:, k] for k, c in enumerate(params)}, times,
                                        points if len(space) > 1 else points[:, 0])
    assert ref.error_estimate < 1e-2 * tolerance
    T, P = np.meshgrid(times, np.arange(points.shape[0]), indexing="ij")
    worst = {u: 0.0 for u in problem.unknown_names}
    for s in range(samples.shape[0]):
        where = {t.name: T.ravel(), **{c.name: points[P.ravel(), a] for a, c in enumerate(space)},
                 **{c.name: np.full(T.size, samples[s, k]) for k, c in enumerate(params)}}
        got = cb.evaluate(where)
        for u in worst:
            worst[u] = max(worst[u], float(np.abs(got[u].reshape(T.shape) - ref.values[u][s]).max()))
    return worst


def solved(path: str):
    problem = pgdcli.load_spec(ROOT / path)
    assert all(c.auto for c in problem.coordinates)  # written without node counts
    return problem, pgdcli.solve(problem)


@pytest.fixture(scope="module")
def allen_cahn2d():
    return solved("problems/allen_cahn2d.yaml")


@pytest.mark.slow
def test_brusselator_within_tolerance_at_random_face_and_corner_points():
    problem, result = solved("problems/brusselator_pde.yaml")
    assert result.accurate, result.message
    assert result.codebook.report["method"].startswith("pde march")
    errors = worst_errors(problem, result.codebook)
    assert set(errors) == {"u", "v"} and max(errors.values()) <= problem.solver.tolerance, errors


@pytest.mark.slow
def test_allen_cahn2d_within_tolerance_at_random_face_and_corner_points(allen_cahn2d):
    problem, result = allen_cahn2d
    assert result.accurate, result.message
    cb = result.codebook
    assert [c.name for c in cb.coordinates] == ["t", "x", "y", "eps"] and cb.coordinate("y").role == "space"
    assert worst_errors(problem, cb)["u"] <= problem.solver.tolerance


@pytest.mark.slow
def test_verify_measures_a_2d_codebook_against_the_nonlinear_reference(allen_cahn2d, tmp_path):
    problem, result = allen_cahn2d
    path = result.codebook.save(tmp_path / "ac2d.h5")
    report = pgdcli.verify(path, samples=2, max_corners=0, times=2, jobs=1, max_error=problem.solver.tolerance)
    assert "nonlinear method of lines" in report.settings["method"]
    assert set(report.settings["space_points"]) == {"x", "y"}
    assert report.passed(problem.solver.tolerance) and not report.failures


@pytest.mark.slow
def test_predator_prey_with_a_saturating_term_within_tolerance():
    """A system written as a user would (tests/user_problems/predator_prey.yaml): Holling type II predation
    u*v/(u + 0.3), a function of both unknowns, zero flux, the efficiency b as a coordinate."""
    problem, result = solved("tests/user_problems/predator_prey.yaml")
    assert result.accurate, result.message
    errors = worst_errors(problem, result.codebook)
    assert set(errors) == {"u", "v"} and max(errors.values()) <= problem.solver.tolerance, errors


@pytest.mark.parametrize("name, edit, reason", [
    ("brusselator_pde", ("+ B*u - u**2*v", "+ B*u - u**2*v + 0.001*der(u, x, 2)"),
     "equations[1]: cross-diffusion der(u, x, 2) in the equation of v"),
    ("brusselator_pde", ("0.01*der(v, x, 2)", "(0.01 - 0.005*B)*der(v, x, 2)"),
     "equations[1]: the diffusion coefficient of v along x, 0.01 - 0.005*B, is -0.005 at B=3: it must be positive"),
    ("allen_cahn2d", ("x: {low: {gradient: 0}, high: {gradient: 0}}", 'x: {low: "1 + y", high: {gradient: 0}}'),
     "unknowns.u.boundary: the conditions on x (low) and on y (low) disagree at the corner x=0, y=0 by 1 "),
])
def test_forms_outside_the_march_are_refused_in_one_line(name, edit, reason, tmp_path):
    spec = tmp_path / "edited.yaml"
    text = (ROOT / "problems" / f"{name}.yaml").read_text()
    if name == "allen_cahn2d":  # u = 1 + y at x = 0 has d/dy 1 where u_y = 0 is asked; the initial value meets it
        text = text.replace('initial: "0.5*cos(pi*x)*cos(pi*y) + 0.3*cos(2*pi*x)"', 'initial: "1 + y - x**2"')
    spec.write_text(text.replace(*edit))
    assert_refused_in_one_line(spec, tmp_path / "out.h5", reason)
