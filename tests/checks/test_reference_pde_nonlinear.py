"""The nonlinear method-of-lines reference against exact solutions.

Burgers: the Cole-Hopf solution, evaluated by the heat-kernel integral (the cosine series of
phi cancels catastrophically for nu = 0.01: phi spans exp(-1/(pi nu)) ~ 1e-14). Fisher's reaction:
a spatially uniform start with gradient conditions gives the logistic solution. Fisher's
diffusion and value/gradient conditions: with r = 0 it is the linear heat equation, solved by the
linear method-of-lines reference. Systems and two space coordinates: manufactured solutions
(tests/manufactured_rd.py).
"""

import numpy as np
import pytest

from pgdcli.checks.reference import solve_reference_pde
from pgdcli.checks.reference_pde_nonlinear import (GEOMETRIC_RATIO, PREDICTION_SAFETY, grid_error_estimate,
                                                  solve_reference_nonlinear_pde)
from pgdcli.errors import SolverError
from pgdcli.problem.spec import load_spec, parse_spec

import manufactured_rd

BURGERS = "problems/burgers.yaml"


def cole_hopf(nu: float, t: np.ndarray, x: np.ndarray, m: int = 8001) -> np.ndarray:
    """Exact u (T, P) of u_t = nu u_xx - u u_x, u(0) = sin(pi x), u = 0 at 0 and 1.

    u = -2 nu phi_x / phi with phi the heat solution from phi0 = exp(-(1 - cos(pi x)) / (2 pi nu))
    (even and 2-periodic, so the whole-line kernel gives the Neumann solution):
    u = int (s / t) G(s) phi0(x - s) ds / int G(s) phi0(x - s) ds, G(s) = exp(-s^2 / (4 nu t)),
    by the trapezoid rule on a fine grid (exponentially accurate), exponents shifted by their max.
    """
    out = np.empty((t.size, x.size))
    for i, ti in enumerate(t):
        half = np.sqrt(4 * nu * ti * 50)  # the kernel below exp(-50)
        s = np.linspace(-half, half, m)
        for j, xj in enumerate(x):
            E = -s ** 2 / (4 * nu * ti) - (1 - np.cos(np.pi * (xj - s))) / (2 * np.pi * nu)
            w = np.exp(E - E.max())
            out[i, j] = np.sum(s / ti * w) / np.sum(w)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("nu", [0.1, 0.01])
def test_burgers_against_cole_hopf(nu):
    problem = load_spec(BURGERS)
    rng = np.random.default_rng(7)
    x = rng.uniform(0, 1, 40)
    t = np.sort(rng.uniform(0.01, 0.5, 8))  # 320 random points
    ref = solve_reference_nonlinear_pde(problem, {"nu": np.array([nu])}, t, x)
    error = np.abs(ref.values["u"][0] - cole_hopf(nu, t, x)).max()
    assert error < 1e-9
    assert ref.error_estimate < 1e-9


def test_a_geometric_fall_predicts_the_next_difference():
    assert grid_error_estimate([3e-4]) == 3e-4  # one difference: itself
    assert grid_error_estimate([1e-3, 1e-4]) == 1e-4  # a slow fall: the last difference
    ratio = GEOMETRIC_RATIO / 10
    predicted = PREDICTION_SAFETY * 1e-6 * ratio
    assert grid_error_estimate([1e-6 / ratio, 1e-6]) == pytest.approx(predicted)
    assert grid_error_estimate([1e-6 / ratio, 1e-6], floor=1e-7) == 1e-7  # the time integration's error stays
    assert grid_error_estimate([1e-6 / ratio, 1e-6], floor=1e-5) == 1e-6  # never above the last difference
    assert grid_error_estimate([0.0, 0.0]) == 0.0


def test_a_predicted_error_bounds_the_next_grids_difference():
    """Burgers at nu = 0.01: 33 -> 65 -> 129 nodes fall spectrally, so 129 nodes are the last solved; the
    257-node solve the prediction saved differs from them by less than the estimate, and so does the exact
    solution."""
    problem = load_spec(BURGERS)
    x = np.random.default_rng(8).uniform(0, 1, 40)
    t = np.linspace(0.05, 0.5, 6)
    ref = solve_reference_nonlinear_pde(problem, {"nu": np.array([0.01])}, t, x)
    assert ref.nodes == 129 and ref.error_estimate < 1e-9
    finer = solve_reference_nonlinear_pde(problem, {"nu": np.array([0.01])}, t, x, start_nodes=257, max_nodes=257)
    assert np.abs(finer.values["u"] - ref.values["u"]).max() <= ref.error_estimate  # measured 4e-12 < 1e-10
    assert np.abs(ref.values["u"][0] - cole_hopf(0.01, t, x)).max() <= ref.error_estimate


FISHER_UNIFORM = """
coordinates:
  t: {domain: [0, 2]}
  x: {domain: [0, 1]}
  r: {domain: [1, 5]}
  c: {domain: [0.1, 0.9]}
unknowns:
  u:
    initial: c
    boundary:
      x: {low: {gradient: 0}, high: {gradient: 0}}
equations:
  - "der(u) = 0.05*der(u, x, 2) + r*u*(1 - u)"
"""


def test_fisher_reaction_is_logistic():
    problem = parse_spec(FISHER_UNIFORM, source="uniform.yaml")
    r, c = np.array([1.0, 5.0, 2.7]), np.array([0.1, 0.9, 0.4])
    t = np.linspace(0, 2, 7)
    x = np.random.default_rng(3).uniform(0, 1, 50)
    ref = solve_reference_nonlinear_pde(problem, {"r": r, "c": c}, t, x)
    e = np.exp(r[:, None] * t[None, :])
    exact = c[:, None] * e / (1 - c[:, None] + c[:, None] * e)
    assert np.abs(ref.values["u"] - exact[:, :, None]).max() < 1e-9


def test_fisher_without_reaction_matches_linear_reference():
    text = open("problems/fisher.yaml").read().replace("+ r*u*(1 - u)", "+ 0*r")
    problem = parse_spec(text, source="heat.yaml")
    D = np.array([0.01, 0.1])
    t = np.array([0.1, 0.5, 1.0])
    x = np.random.default_rng(4).uniform(0, 1, 60)
    ref = solve_reference_nonlinear_pde(problem, {"D": D, "r": np.ones(2)}, t, x)
    linear = solve_reference_pde(problem, {"D": D, "r": np.ones(2)}, {"x": x}, t, space_nodes=129)
    assert np.abs(ref.values["u"] - linear.values["u"]).max() < 1e-8


def test_two_space_coordinates_against_an_exact_solution():
    """Allen-Cahn with a source on the unit square: y-dependent values at x = 1, gradients on y = 0 and 1."""
    problem = parse_spec(manufactured_rd.PLANE, source="plane.yaml")
    rng = np.random.default_rng(5)
    points = rng.uniform(0, 1, (80, 2))
    times = np.array([0.0, 0.4, 1.0])
    c = np.array([0.05, 0.1])
    ref = solve_reference_nonlinear_pde(problem, {"c": c}, times, points)
    exact = manufactured_rd.plane_exact(times[:, None], points[None, :, 0], points[None, :, 1])
    assert np.abs(ref.values["u"] - exact[None]).max() < 1e-9  # measured 4e-12
    grid = solve_reference_nonlinear_pde(problem, {"c": c}, times, [points[:5, 0], points[:7, 1]], grid=True)
    exact = manufactured_rd.plane_exact(times[:, None, None], points[None, :5, 0, None], points[None, None, :7, 1])
    assert grid.values["u"].shape == (2, 3, 5, 7) and np.abs(grid.values["u"] - exact[None]).max() < 1e-9


def test_two_species_against_an_exact_solution():
    """Two species coupled by u*v/(1 + u) (a general atom: its Jacobian by differences) and v*der(u, x)."""
    problem = parse_spec(manufactured_rd.PAIR, source="pair.yaml")
    a = np.array([0.5, 1.3])
    x = np.random.default_rng(6).uniform(0, 1, 60)
    times = np.array([0.2, 1.0])
    ref = solve_reference_nonlinear_pde(problem, {"a": a}, times, x)
    u, v = manufactured_rd.pair_exact(times[None, :, None], x[None, None, :], a[:, None, None])
    assert np.abs(ref.values["u"] - u).max() < 1e-9 and np.abs(ref.values["v"] - v).max() < 1e-9  # 1e-11


def test_three_space_coordinates_are_refused():
    text = open("tests/user_problems/burgers_2d.yaml").read().replace("  y: {domain: [0, 1]}",
                                                                      "  y: {domain: [0, 1]}\n  z: {domain: [0, 1]}")
    text = text.replace("      y: {low: 0, high: 0}", "      y: {low: 0, high: 0}\n      z: {low: 0, high: 0}")
    problem = parse_spec(text.replace("der(u, y, 2))", "der(u, y, 2) + der(u, z, 2))"), source="b3.yaml")
    with pytest.raises(SolverError, match="takes one or two space coordinates, got 3"):
        solve_reference_nonlinear_pde(problem, {}, np.array([0.5]), np.array([[0.5, 0.5, 0.5]]))


def test_samples_on_threads_are_the_samples_one_after_another(monkeypatch):
    from pgdcli import executors
    from pgdcli.checks import reference_pde_nonlinear
    from pgdcli.checks.reference_pde_nonlinear import solve_reference_nonlinear_grid

    problem = parse_spec(manufactured_rd.PLANE, source="plane.yaml")  # two space coordinates
    params, times = {"c": np.array([0.05, 0.1, 0.08])}, np.array([0.0, 0.4, 1.0])
    points = {"x": np.linspace(0, 1, 5), "y": np.linspace(0, 1, 4)}
    started, submit = [], executors.ThreadExecutor.submit

    def recorded(self, fn, *args):
        started.append(self.workers)
        return submit(self, fn, *args)

    monkeypatch.setattr(executors.ThreadExecutor, "submit", recorded)
    found = {}
    for cores in (1, 2):
        reference_pde_nonlinear._SOLUTIONS.clear()  # solved again, not read from the cache
        monkeypatch.setattr(executors, "free_cores", lambda: cores)
        found[cores] = solve_reference_nonlinear_grid(problem, params, points, times)
        assert found[cores].success.all()
    assert started == [2] * 3  # two cores: the three samples went to the threads
    assert np.array_equal(found[1].values["u"], found[2].values["u"])
    started.clear()
    fisher = parse_spec(FISHER_UNIFORM, source="uniform.yaml")  # one space coordinate: its small grids stay here
    solve_reference_nonlinear_grid(fisher, {"r": np.array([1.0, 5.0]), "c": np.array([0.1, 0.9])},
                                   {"x": np.linspace(0, 1, 9)}, np.linspace(0, 2, 5))
    assert started == []


def test_samples_solved_by_worker_processes_are_the_same_and_kept_here(monkeypatch):
    """A pool's workers solve the samples as this process does, bit for bit, and send their solutions back:
    the next call (the next round's gate) is served from this process's cache."""
    from pgdcli import executors
    from pgdcli.checks import reference_pde_nonlinear as nonlinear

    problem = load_spec("problems/fisher.yaml")
    params = {"D": np.array([0.02, 0.08]), "r": np.array([1.5, 4.0])}
    times, space = np.array([0.0, 1.3, 4.0, 10.0]), {"x": np.linspace(0, 1, 7)}
    monkeypatch.setattr(executors, "free_cores", lambda: 1)
    nonlinear._SOLUTIONS.clear()
    here = nonlinear.solve_reference_nonlinear_grid(problem, params, space, times)
    nonlinear._SOLUTIONS.clear()
    with executors.ProcessExecutor(2) as pool:
        there = nonlinear.solve_reference_nonlinear_grid(problem, params, space, times, executor=pool)
    assert there.success.all() and np.array_equal(there.values["u"], here.values["u"])
    monkeypatch.setattr(nonlinear, "CollocatedModel", None)  # nothing solved again: the workers' solutions
    again = nonlinear.solve_reference_nonlinear_grid(problem, params, space, times)
    assert np.array_equal(again.values["u"], here.values["u"])


def test_the_samples_run_where_the_idle_cores_are(monkeypatch):
    """One space coordinate: forked processes on the idle cores (its Radau steps hold the GIL); none idle, or
    every sample solved before: here. Two: threads (Radau's LU of the grid releases it)."""
    from pgdcli import executors
    from pgdcli.checks import reference_pde_nonlinear as nonlinear

    class Fork:
        @staticmethod
        def get_start_method():
            return "fork"

    monkeypatch.setattr(executors, "pool_context", Fork)
    fisher = load_spec("problems/fisher.yaml")
    samples = [{"D": np.array([0.02]), "r": np.array([1.5])}, {"D": np.array([0.03]), "r": np.array([2.0])}]
    nonlinear._SOLUTIONS.clear()
    for cores, kind, own in ((2, executors.ProcessExecutor, True), (1, executors.SerialExecutor, False)):
        monkeypatch.setattr(executors, "free_cores", lambda: cores)
        runner, _, mine = nonlinear._runner(fisher, None, samples, 1, np.array([0.0, 1.0]), [np.zeros(3)])
        assert isinstance(runner, kind) and mine is own
    monkeypatch.setattr(executors, "free_cores", lambda: 2)
    runner, _, _ = nonlinear._runner(fisher, None, samples, 2, np.array([0.0, 1.0]), [np.zeros(3)])
    assert isinstance(runner, executors.ThreadExecutor)
    for sample in samples:
        nonlinear._remember((fisher.source_text, nonlinear._sample_key(sample), 33, 10.0, 1e-10, 1e-10), None)
    runner, _, _ = nonlinear._runner(fisher, None, samples, 1, np.array([0.0, 1.0]), [np.zeros(3)])
    assert isinstance(runner, executors.SerialExecutor)
    nonlinear._SOLUTIONS.clear()
