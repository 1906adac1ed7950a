"""Nonlinear PDEs in one space coordinate through pgdcli.solve / pgd solve.

Shipped (problems/fisher.yaml, problems/burgers.yaml) and fresh user-style problems written without
node counts; each codebook the solver calls accurate is measured at 300 random points (5 parameter
samples x 6 times x 10 space points) against the independent nonlinear method of lines
(pgdcli.checks.reference_pde_nonlinear: its own Chebyshev collocation, Radau at 1e-11, grids refined
until two agree to 1e-9; itself checked against the exact Cole-Hopf solution in
tests/checks/test_reference_pde_nonlinear.py). What the march cannot take is refused with one line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pgdcli
from pgdcli.checks.reference_pde_nonlinear import solve_reference_nonlinear_pde

from cli_refusal import assert_refused_in_one_line, pgd_solve

ROOT = Path(__file__).resolve().parents[2]


def worst_error(problem, cb, seed: int = 14) -> float:
    """Max abs error of the codebook at 5 x 6 x 10 = 300 random points against the reference."""
    rng = np.random.default_rng(seed)
    params = [c for c in problem.coordinates if c.role == "parameter"]
    t = problem.time_coordinate
    x = next(c for c in problem.coordinates if c.role == "space")
    samples = {c.name: rng.uniform(*c.domain, 5) for c in params}
    times = np.sort(rng.uniform(*t.domain, 6))
    points = rng.uniform(*x.domain, 10)
    # grids agreeing to 1e-8: 1% of the tolerances here, and fewer nodes than the default 1e-9 may need
    ref = solve_reference_nonlinear_pde(problem, samples, times, points, space_tolerance=1e-8)
    assert ref.error_estimate < 1e-8
    T, X = np.meshgrid(times, points, indexing="ij")
    worst = 0.0
    for s in range(5):
        where = {t.name: T.ravel(), x.name: X.ravel(), **{k: np.full(T.size, v[s]) for k, v in samples.items()}}
        got = cb.evaluate(where)["u"].reshape(T.shape)
        worst = max(worst, float(np.abs(got - ref.values["u"][s]).max()))
    return worst


def solved(path: str):
    problem = pgdcli.load_spec(ROOT / path)
    assert all(c.auto for c in problem.coordinates)  # written without node counts
    return problem, pgdcli.solve(problem)


@pytest.mark.slow
@pytest.mark.parametrize("path", ["problems/fisher.yaml", "problems/burgers.yaml",
                                  "tests/user_problems/allen_cahn.yaml", "tests/user_problems/nagumo.yaml",
                                  "tests/user_problems/burgers_source.yaml"])
def test_solves_within_tolerance_at_random_points(path):
    problem, result = solved(path)
    assert result.accurate, result.message
    assert result.codebook.report["method"].startswith("pde march")
    assert worst_error(problem, result.codebook) <= problem.solver.tolerance


@pytest.mark.parametrize("edit, reason", [
    (("der(u) = D*der(u, x, 2)", "der(u) = exp(x)*der(u, x, 2)"), "must not depend on x"),
    (("der(u) = D*der(u, x, 2)", "der(u) = (D - 0.05)*der(u, x, 2)"), "must be positive"),
])
def test_unsupported_forms_are_refused_with_one_line(edit, reason, tmp_path):
    spec = tmp_path / "fisher_edit.yaml"
    spec.write_text((ROOT / "problems" / "fisher.yaml").read_text().replace(*edit))
    assert_refused_in_one_line(spec, tmp_path / "out.h5", reason)


def test_three_space_coordinates_are_refused(tmp_path):
    text = (ROOT / "tests" / "user_problems" / "burgers_2d.yaml").read_text()
    text = text.replace("  y: {domain: [0, 1]}", "  y: {domain: [0, 1]}\n  z: {domain: [0, 1]}")
    text = text.replace("      y: {low: 0, high: 0}", "      y: {low: 0, high: 0}\n      z: {low: 0, high: 0}")
    spec = tmp_path / "burgers_3d.yaml"
    text = text.replace('"sin(pi*x)*sin(pi*y)"', '"sin(pi*x)*sin(pi*y)*sin(pi*z)"')
    spec.write_text(text.replace("der(u, y, 2))", "der(u, y, 2) + der(u, z, 2))"))
    run = pgd_solve(spec, tmp_path / "out.h5")
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 2 and len(lines) == 1 and "3 space coordinates (x, y, z); at most 2" in lines[0], run.stderr


BURGERS_MILD = (ROOT / "problems" / "burgers.yaml").read_text().replace("[0.01, 0.1]", "[0.05, 0.1]")


@pytest.mark.slow
def test_burgers_mild_solves_and_verify_uses_the_nonlinear_reference(tmp_path):
    """burgers.yaml with nu in [0.05, 0.1]: the codebook within the tolerance at 300 random points, and
    pgd verify on it measures against the nonlinear method of lines."""
    problem = pgdcli.parse_spec(BURGERS_MILD, source="burgers_mild.yaml")
    result = pgdcli.solve(problem)
    assert result.accurate, result.message
    assert worst_error(problem, result.codebook) <= 1e-6
    path = tmp_path / "mild.h5"
    result.codebook.save(path)
    report = pgdcli.verify(path, samples=4, jobs=1, max_error=1e-6)
    assert "nonlinear method of lines" in report.settings["method"]
    assert report.passed(1e-6) and not report.failures


@pytest.mark.slow
def test_a_codebook_missing_the_tolerance_is_refused_and_not_written(tmp_path):
    """Too few x nodes fixed by the spec: the gate measures the error against the nonlinear reference
    and pgd solve exits 1 with nothing written."""
    spec = tmp_path / "coarse.yaml"
    spec.write_text(BURGERS_MILD.replace("x: {domain: [0, 1]}", "x: {domain: [0, 1], nodes: 9}"))
    out = tmp_path / "coarse.h5"
    run = pgd_solve(spec, out)
    assert run.returncode == 1, run.stderr
    assert "tolerance not met" in run.stderr and "'x'" in run.stderr and "Traceback" not in run.stderr
    assert not out.exists()
