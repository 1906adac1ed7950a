"""The grid march (pgdcli.algorithms.grid_march): the whole array of a small grid marched by DOP853.

Its right-hand side must equal the tensor-train march's (the same compiled system evaluated two
ways), and its states the trajectories of scipy's solve_ivp (DOP853, rtol = atol = 1e-12) at the
grid's initial conditions, written here in numpy.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import PROBLEMS
from scipy.integrate import solve_ivp
from threadpoolctl import threadpool_limits

import pgdcli
from pgdcli import load_spec, parse_spec
from pgdcli.algorithms import grid_march
from pgdcli.algorithms.march import compile_system, evaluate_rhs
from pgdcli.algorithms.outcome import Status
from pgdcli.tensors.tt import tt_rank_one, tt_sum

TIMED = """
name: timed
coordinates:
  t: {domain: [0, 2]}
  w: {domain: [1, 3]}
  u0: {domain: [0.5, 1.5]}
unknowns:
  u: {initial: u0}
  v: {initial: 0}
equations:
  - "der(u) = v"
  - "der(v) = -w*w*u - 0.2*v*sqrt(1 + v*v) + cos(w*t)*exp(-u*u)"
solver:
  tolerance: 1e-7
"""


def random_state(system, seed: int):
    """A rank-2 train per unknown, of moderate values, on the system's grid."""
    rng = np.random.default_rng(seed)
    return [tt_sum([tt_rank_one([rng.uniform(0.2, 1.0, n) for n in system.shape]) for _ in range(2)])
            for _ in system.unknowns]


@pytest.mark.parametrize("source", ["coupled", "pendulum", "timed"])
def test_grid_rhs_equals_the_train_rhs(source):
    problem = parse_spec(TIMED, source="timed.yaml") if source == "timed" else load_spec(PROBLEMS / f"{source}.yaml")
    system = compile_system(problem, 1e-8)
    state = random_state(system, 3)
    rhs = grid_march.GridRhs(system)
    y = np.stack([u.full().reshape(-1) for u in state])
    for t in (0.0, 0.37):
        trains = evaluate_rhs(system, t, state, 1e-14, 400, np.random.default_rng(0), {})
        expected = np.stack([f.full().reshape(-1) for f in trains])
        np.testing.assert_allclose(rhs(t, y), expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())


@pytest.mark.parametrize("chunk_floats", [grid_march.CHUNK_FLOATS, 24000 * 16])
def test_states_at_the_time_nodes_match_solve_ivp(chunk_floats, monkeypatch):
    """Compressed at once or by runs of about 20 time nodes (joined afterwards), within the tolerance."""
    monkeypatch.setattr(grid_march, "CHUNK_FLOATS", chunk_floats)
    problem = load_spec(PROBLEMS / "coupled.yaml")
    system = compile_system(problem, 1e-9)
    with threadpool_limits(1):
        result = grid_march.march_on_grid(system, 1e-9, 1e-10 * np.sqrt(8000), slab_nodes=8)
    assert result.breakpoints[-1] == 0.5 and len(result.times) == result.steps * 7 + 1
    assert (result.chunks == 1) == (chunk_floats > 1e6)
    full = [train.full().reshape(len(result.times), -1) for train in result.trains]
    nodes = [system.bases[p].nodes for p in system.params]
    a, b, c = (g.reshape(-1) for g in np.meshgrid(*nodes, indexing="ij"))
    rng = np.random.default_rng(8)
    worst = 0.0
    for i in rng.choice(a.size, 40, replace=False):
        sol = solve_ivp(lambda t, u: [1 - u[1] * u[2], 2 - u[0] * u[2], 3 - u[0] * u[1]], (0, 0.5),
                        [a[i], b[i], c[i]], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=result.times)
        got = np.stack([f[:, i] for f in full])  # (unknowns, times)
        worst = max(worst, float(np.abs(got - sol.y).max()))
    assert worst <= 1e-9, worst


def test_timed_general_problem_solves_to_its_tolerance_by_the_grid_march():
    problem = parse_spec(TIMED, source="timed.yaml")
    result = pgdcli.solve(problem)
    assert result.accurate, result.message
    assert result.codebook.report["march"] == "grid"
    rng = np.random.default_rng(9)
    worst = 0.0
    for _ in range(60):
        w, u0, t = rng.uniform(1, 3), rng.uniform(0.5, 1.5), rng.uniform(0, 2)
        sol = solve_ivp(lambda s, y: [y[1], -w * w * y[0] - 0.2 * y[1] * np.sqrt(1 + y[1] ** 2) + np.cos(w * s) * np.exp(-y[0] ** 2)],
                        (0, 2), [u0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=[t])
        got = result.codebook(t=t, w=w, u0=u0)
        worst = max(worst, abs(float(got["u"]) - sol.y[0, 0]), abs(float(got["v"]) - sol.y[1, 0]))
    assert worst <= 1e-7, worst


def test_only_small_grids_fit():
    system = compile_system(load_spec(PROBLEMS / "coupled.yaml"), 1e-9)  # 20^3 nodes x 3 unknowns
    assert grid_march.fits_grid(system)
    rigid = (PROBLEMS / "rigid_body.yaml").read_text()
    assert grid_march.fits_grid(compile_system(parse_spec(rigid, source="r.yaml"), 1e-5))  # 8^6 nodes x 6 unknowns
    rigid = rigid.replace("nodes: 8}", "nodes: 10}")  # 10^6 nodes x 6 unknowns
    assert not grid_march.fits_grid(compile_system(parse_spec(rigid, source="r.yaml"), 1e-5))


def test_a_very_stiff_problem_marches_at_its_stability_limit():
    """u' = r (u - u^3), r up to 2000: the train march's stage roundings, amplified by the Jacobian -2r,
    ended it in a step-size underflow; the grid march has no roundings and takes ~700 steps at the
    stability limit. Exact: u = u0 / sqrt(u0^2 + (1 - u0^2) exp(-2 r t)), at the parameter nodes
    (between them 12 nodes do not resolve r)."""
    spec = """
name: stiff
coordinates:
  t: {domain: [0, 1], nodes: 8}
  r: {domain: [10, 2000], nodes: 12}
  u0: {domain: [0.5, 1.5], nodes: 8}
unknowns:
  u: {initial: u0}
equations:
  - "der(u) = r*(u - u**3)"
solver:
  tolerance: 1e-6
  integrator: dop853  # explicit on purpose (auto switches to RODAS4 here)
"""
    # the march controls an RMS over the grid; the error gate tightens it until the nodes meet the max error
    from pgdcli.driver.method import Settings
    from pgdcli.driver.methods import choose_method
    from pgdcli.driver.refinement import solve_rounds

    problem = parse_spec(spec, source="stiff.yaml")
    with threadpool_limits(1):
        result, _ = solve_rounds(problem, choose_method(problem), Settings(1e-6, 0.0, problem.solver.max_modes))
    # the march converged (its codebook is refused between the nodes of r, which 12 nodes do not resolve)
    assert result.status in (Status.CONVERGED, Status.INACCURATE) and result.check.node_ratio <= 1.0, result.message
    rep = result.codebook.report
    assert rep["march"] == "grid" and rep["steps"] > 300  # the stability limit, not the accuracy, sets the steps
    cb = result.codebook
    t = cb.coordinate("t").basis().nodes[:, None, None]
    r = cb.coordinate("r").basis().nodes[None, :, None]
    u0 = cb.coordinate("u0").basis().nodes[None, None, :]
    exact = u0 / np.sqrt(u0 * u0 + (1.0 - u0 * u0) * np.exp(-2.0 * r * t))
    assert np.max(np.abs(cb.nodal_values("u") - exact)) <= 1e-6


RELAXATION = """
name: relaxation
coordinates:
  t: {domain: [0, 4]}
  k: {domain: [500, 1000]}
  y0: {domain: [0, 1], nodes: 4}
unknowns:
  y: {initial: y0}
equations:
  - "der(y) = -k*(y - cos(t)) - 0.1*y**3"
solver:
  tolerance: 1e-6
  integrator: dop853  # explicit on purpose: thousands of steps (auto switches to RODAS4 here)
"""


def test_a_stiff_march_of_thousands_of_slabs_is_checked_on_a_subset_of_its_time_nodes():
    """Fast relaxation onto a slow forcing: DOP853 steps at its stability limit (~3000 steps, one
    slab each: ~24,000 time nodes). The time basis is only interpolated (its n x n derivative was
    built, 4.8 GB, and so was an n x n identity for the one-point path), and the gate and verify
    compare at every k-th node (their references cost a solve_ivp segment per output time). The
    codebook against scipy's Radau at random points; max_steps below the stability limit's count
    says what the steps were."""
    from scipy.integrate import solve_ivp

    from pgdcli.checks.sampling import CHECK_TIME_NODES
    from pgdcli.checks.verify import verify

    with threadpool_limits(1):
        result = pgdcli.solve(parse_spec(RELAXATION, source="relaxation.yaml"))
    assert result.converged, result.message
    cb = result.codebook
    n_time = cb.coordinate("t").basis().nodes.size
    assert cb.report["steps"] > 1000 and n_time > 10 * CHECK_TIME_NODES
    assert f"of the {n_time} time nodes" in cb.report["check_method"]
    rng = np.random.default_rng(5)
    times = np.concatenate([[0.0, 1e-3, 4.0], rng.uniform(0, 4, 20)])
    for k, y0 in rng.uniform((500, 0), (1000, 1), (6, 2)):
        ref = solve_ivp(lambda t, y: -k * (y - np.cos(t)) - 0.1 * y**3, (0, 4), [y0], method="Radau",
                        rtol=1e-12, atol=1e-14, t_eval=np.sort(times), dense_output=False)
        got = cb(t=np.sort(times), k=k, y0=y0)["y"]
        assert np.max(np.abs(got - ref.y[0])) <= 1e-6
    assert cb(t=float(cb.coordinate("t").basis().nodes[7]), k=500.0, y0=1.0)["y"].shape == ()  # on a node
    report = verify(cb, samples=8, times=4)
    assert report.passed() and report.settings["time_nodes_total"] == n_time
    assert report.settings["time_nodes"] <= CHECK_TIME_NODES + 1

    capped = RELAXATION.replace("tolerance: 1e-6", "tolerance: 1e-6\n  max_steps: 500")
    result = pgdcli.solve(parse_spec(capped, source="relaxation.yaml"))
    assert not result.converged
    assert "max_steps=500 reached (steps of" in result.message and "raise solver.max_steps" in result.message


@pytest.mark.parametrize("march", ["train", "grid"])
def test_solver_march_chooses_the_state(march):
    """``solver.march: train`` keeps a small grid in a tensor train; ``grid`` marches the array (the
    default ``auto`` would take the grid here); both within the tolerance at the nodes' check."""
    text = (PROBLEMS / "logistic.yaml").read_text() + f"  march: {march}\n"
    result = pgdcli.solve(parse_spec(text, source="logistic.yaml"))
    assert result.accurate, result.message
    assert result.codebook.report["march"] == march



def test_forced_grid_above_its_memory_cap_is_one_error_line(tmp_path):
    from click.testing import CliRunner

    from pgdcli.cli.main import cli

    text = (PROBLEMS / "coupled.yaml").read_text().replace("nodes: 20", "nodes: 240") + "  march: grid\n"
    path = tmp_path / "big.yaml"
    path.write_text(text)
    result = CliRunner().invoke(cli, ["solve", str(path), "-o", str(tmp_path / "big.h5")])
    assert result.exit_code == 2, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0] == (
        f"Error: {path}: solver.march: 'grid' holds ~20 arrays of the state, which has 41,472,000 values (grid "
        f"nodes x unknowns; at most 33,554,432): use 'auto' or 'train' (a tensor train), or fewer nodes")
    assert not (tmp_path / "big.h5").exists()


@pytest.mark.parametrize("march", ["train", "grid"])
def test_pgd_solve_json_and_info_say_which_march(march, tmp_path):
    import json

    from click.testing import CliRunner

    from pgdcli.cli.main import cli

    path = tmp_path / "logistic.yaml"
    path.write_text((PROBLEMS / "logistic.yaml").read_text() + f"  march: {march}\n")
    out = tmp_path / "l.h5"
    solved = CliRunner().invoke(cli, ["solve", str(path), "-o", str(out), "-q", "--format", "json"])
    assert solved.exit_code == 0, solved.output
    assert json.loads(solved.stdout)["march"] == march
    info = json.loads(CliRunner().invoke(cli, ["info", str(out), "--format", "json"]).stdout)
    assert info["march"] == march and ("roundings" in info) == (march == "train")


@pytest.mark.parametrize("chunk_floats", [10 ** 9, 5000, 1200])
def test_the_store_meets_its_bound_at_once_or_by_runs(chunk_floats, monkeypatch):
    """The space-time trains are within ``delta`` (Frobenius) of the stored values, however many runs."""
    monkeypatch.setattr(grid_march, "CHUNK_FLOATS", chunk_floats)
    grid = np.linspace(0.0, 1.0, 12)
    a, b = np.meshgrid(grid, grid, indexing="ij")
    times = np.linspace(0.0, 2.0, 60)
    values = [np.stack([np.sin(3 * t * a + b) * np.exp(-t * b), np.cos(t + a * b)]).reshape(2, -1) for t in times]
    exact = np.stack(values)  # (times, unknowns, grid nodes)
    delta = 1e-6 * np.linalg.norm(exact[:, 0])
    store = grid_march._Store((12, 12), delta)
    for start in range(0, len(values), 7):  # as the march stores a step's nodes
        store.extend(values[start:start + 7])
    trains = store.trains()
    assert (len(store.pieces) > 1) == (chunk_floats < 10 ** 9)
    for i, train in enumerate(trains):
        error = np.linalg.norm(train.full().reshape(len(times), -1) - exact[:, i])
        assert error <= delta, (i, error, delta)
