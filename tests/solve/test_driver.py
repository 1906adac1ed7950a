"""PGD solver accuracy and reporting (pgdcli.driver) against exact solutions and scipy.

Accuracy is measured at >= 500 uniform random points plus every corner of the
domain; references are the closed-form solutions in problems/*.yaml (see
conftest.py) or scipy's solve_ivp, never values computed by pgdcli.
"""

from __future__ import annotations

import math
import textwrap

import numpy as np
import pytest
from conftest import EXACT, PROBLEMS, codebook_points, exact_spring, max_abs_error, random_points, assert_solved, spec_text
from scipy.integrate import solve_ivp

from pgdcli import Codebook, load_spec, parse_spec, solve
from pgdcli.errors import SolverError
from pgdcli.tensors.cp import CPTensor
from pgdcli.algorithms.enrichment import residual_norm
from pgdcli.algorithms.enrichment_solve import solve_enrichment
from pgdcli.driver import SolveResult
from pgdcli.discretization.linear import STATE, discretize

N_POINTS = 1000
SEEDS = {"parametric": 101, "spring": 202, "relaxation": 303}


# ----------------------------------------------------------------------------------------------
# shipped problems against their exact solutions
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name,bound",
    [("parametric", 1e-10), ("spring", 1e-8), ("relaxation", 1e-8)],
)
def test_shipped_problem_matches_exact_solution(solved, name, bound):
    result = solved(name)
    assert result.converged, result.message
    cb = result.codebook
    points = codebook_points(cb, N_POINTS, seed=SEEDS[name])
    errors = max_abs_error(cb, EXACT[name], points)
    assert max(errors.values()) <= bound, errors


def test_parametric_nodal_values_are_exact(solved):
    # the exact solution is linear in t and the k-dependence is 1/k at the nodes: nodal values are exact
    cb = solved("parametric").codebook
    t, k = (c.basis().nodes for c in cb.coordinates)
    ref = (10.0 / k[None, :] - 1.0) * t[:, None]
    np.testing.assert_allclose(cb.nodal_values("u"), ref, rtol=0, atol=1e-12)


def test_initial_condition_is_imposed_exactly(solved):
    # the lift carries u(t0): at t = t0 the PGD part vanishes identically
    cb = solved("relaxation").codebook
    p = random_points({"k": (0.5, 5.0), "a": (-1.0, 1.0), "u0": (0.0, 1.0)}, 200, seed=4)
    u = cb(t=0.0, **p)["u"]
    np.testing.assert_allclose(u, p["u0"], rtol=0, atol=1e-14)
    cb = solved("spring").codebook
    v = cb(t=0.0, k=np.linspace(1, 4, 7), c=0.3)
    np.testing.assert_allclose(v["x"], 1.0, rtol=0, atol=1e-14)
    np.testing.assert_allclose(v["v"], 0.0, rtol=0, atol=1e-14)


def _variant(name: str, replacements: dict[str, str]):
    text = (PROBLEMS / f"{name}.yaml").read_text()
    for old, new in replacements.items():
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return parse_spec(text, source=f"{name}-variant.yaml")


def test_error_falls_as_time_nodes_are_added():
    # spectral regime of the time discretization (larger counts hit the 1e-10 tolerance floor)
    points = random_points({"t": (0.0, 4.0), "k": (1.0, 4.0), "c": (0.1, 0.5)}, 500, seed=21)
    errors = []
    for nt in (10, 12, 14, 16):
        result = solve(_variant("spring", {"t: {domain: [0, 4], nodes: 36}": f"t: {{domain: [0, 4], nodes: {nt}}}"}))
        assert_solved(result)
        errors.append(max(max_abs_error(result.codebook, exact_spring, points).values()))
    assert all(e2 < e1 / 10 for e1, e2 in zip(errors[:-1], errors[1:])), errors


def test_linear_time_elements_converge_at_second_order():
    template = textwrap.dedent(
        """\
        coordinates:
          t: {domain: [0, 2], nodes: %d, discretization: linear}
          k: {domain: [0.5, 3], nodes: 16}
        unknowns:
          u: {initial: 1}
        equations:
          - der(u) = -k*u
        solver: {tolerance: 1e-12}
        """
    )
    points = random_points({"t": (0.0, 2.0), "k": (0.5, 3.0)}, 600, seed=8)
    errors = []
    for n in (20, 40, 80):
        result = solve(parse_spec(template % n))
        assert_solved(result)
        assert result.codebook.coordinate("t").discretization == "linear"
        errors.append(np.max(np.abs(result.codebook(**points)["u"] - np.exp(-points["k"] * points["t"]))))
    orders = [math.log2(e1 / e2) for e1, e2 in zip(errors[:-1], errors[1:])]
    assert all(1.8 <= p <= 2.2 for p in orders), (errors, orders)


def test_linear_elements_exact_for_solution_linear_in_parameter():
    # u' = -u + a, u(0) = 0  ->  u = a (1 - exp(-t)): linear in a, so 3 hat functions are exact
    spec = textwrap.dedent(
        spec_text(
            coordinates={'t': '{domain: [0, 2], nodes: 20}', 'a': '{domain: [-1, 2], nodes: 3, discretization: linear}'},
            equations=['der(u) = -u + a'],
            solver=' {tolerance: 1e-12}',
        )
    )
    result = solve(parse_spec(spec))
    assert result.converged, result.message
    p = random_points({"t": (0.0, 2.0), "a": (-1.0, 2.0)}, 600, seed=12)
    err = np.max(np.abs(result.codebook(**p)["u"] - p["a"] * (1.0 - np.exp(-p["t"]))))
    assert err <= 1e-12


def test_galerkin_formulation_solves_parametric_problem():
    problem = _variant("parametric", {"tolerance: 1e-12": "tolerance: 1e-12\n  formulation: galerkin"})
    assert problem.solver.formulation == "galerkin"
    result = solve(problem)
    assert result.converged, result.message
    assert result.codebook.report["formulation"] == "galerkin"
    points = codebook_points(result.codebook, 600, seed=3)
    assert max_abs_error(result.codebook, EXACT["parametric"], points)["u"] <= 1e-10


def test_coupled_system_with_time_dependent_coefficient_matches_solve_ivp():
    spec = textwrap.dedent(
        spec_text(
            coordinates={'t': '{domain: [0, 3], nodes: 40}', 'k': '{domain: [1, 3], nodes: 16}'},
            unknowns={'x': '{initial: 1}', 'v': '{initial: 0}'},
            equations=['der(x) = v', 'der(v) = -k*x - 0.3*cos(t)*v + exp(-t)*k'],
            solver=' {tolerance: 1e-12}',
        )
    )
    result = solve(parse_spec(spec))
    assert_solved(result)
    cb = result.codebook
    assert cb.unknown_names == ["x", "v"]
    rng = np.random.default_rng(17)
    worst = 0.0
    n_points = 0
    for k in np.concatenate([rng.uniform(1.0, 3.0, 8), [1.0, 3.0]]):
        ts = np.concatenate([[0.0], np.sort(rng.uniform(0.0, 3.0, 60)), [3.0]])
        ref = solve_ivp(
            lambda t, y: [y[1], -k * y[0] - 0.3 * np.cos(t) * y[1] + np.exp(-t) * k],
            (0.0, 3.0), [1.0, 0.0], t_eval=ts, rtol=1e-12, atol=1e-12, method="DOP853",
        )
        assert ref.success
        got = cb(t=ts, k=k)
        worst = max(worst, np.max(np.abs(got["x"] - ref.y[0])), np.max(np.abs(got["v"] - ref.y[1])))
        n_points += ts.size
    assert n_points >= 500
    assert worst <= 1e-9


def _solve_text(text):
    result = solve(parse_spec(textwrap.dedent(text)))
    assert_solved(result)
    return result.codebook


def test_time_need_not_be_the_first_coordinate():
    cb = _solve_text(
        spec_text(
            coordinates={'k': '{domain: [1, 10], nodes: 56}', 't': '{domain: [0, 10], nodes: 8}'},
            equations=['"k*(der(u) + 1) = 10"'],
            solver=' {tolerance: 1e-12}',
        )
    )
    assert cb.coordinate_names == ["k", "t"]
    p = random_points({"k": (1.0, 10.0), "t": (0.0, 10.0)}, 600, seed=31)
    assert np.max(np.abs(cb(**p)["u"] - (10.0 / p["k"] - 1.0) * p["t"])) <= 1e-10


def test_shifted_time_origin_named_tau_and_expression_initial_value():
    # du/dtau = -k u, u(1) = exp(-k)  ->  u = exp(-k tau)
    cb = _solve_text(
        spec_text(
            coordinates={'tau': '{domain: [1, 3], nodes: 24}', 'k': '{domain: [0.5, 2], nodes: 20}'},
            time=' tau',
            unknowns={'u': '{initial: "exp(-k)"}'},
            equations=['der(u) = -k*u'],
            solver=' {tolerance: 1e-12}',
        )
    )
    p = random_points({"tau": (1.0, 3.0), "k": (0.5, 2.0)}, 600, seed=32)
    assert np.max(np.abs(cb(**p)["u"] - np.exp(-p["k"] * p["tau"]))) <= 1e-10


def test_time_dependent_coefficient_on_the_derivative():
    # (1 + t) u' = -k u, u(0) = 1  ->  u = (1 + t)^-k
    cb = _solve_text(
        spec_text(
            coordinates={'t': '{domain: [0, 2], nodes: 30}', 'k': '{domain: [1, 2], nodes: 10}'},
            unknowns={'u': '{initial: 1}'},
            equations=['(1 + t)*der(u) = -k*u'],
            solver=' {tolerance: 1e-12}',
        )
    )
    p = random_points({"t": (0.0, 2.0), "k": (1.0, 2.0)}, 600, seed=33)
    assert np.max(np.abs(cb(**p)["u"] - (1.0 + p["t"]) ** -p["k"])) <= 1e-10


def test_problem_with_time_as_the_only_coordinate():
    # u' = -u + sin(t), u(0) = 1: no parameter coordinates at all
    cb = _solve_text(
        spec_text(
            coordinates={'t': '{domain: [0, 2], nodes: 24}'},
            unknowns={'u': '{initial: 1}'},
            equations=['der(u) = -u + sin(t)'],
            solver=' {tolerance: 1e-12}',
        )
    )
    t = random_points({"t": (0.0, 2.0)}, 600, seed=34)["t"]
    exact = 1.5 * np.exp(-t) + (np.sin(t) - np.cos(t)) / 2.0
    assert np.max(np.abs(cb(t=t)["u"] - exact)) <= 1e-10


def test_zero_problem_gives_zero_codebook(tmp_path):
    cb = _solve_text(
        spec_text(
            coordinates={'t': '{domain: [0, 1], nodes: 6}', 'k': '{domain: [0.5, 2], nodes: 5}'},
            equations=['der(u) = -k*u'],
        )
    )
    cb.save(tmp_path / "zero.h5")
    out = Codebook.load(tmp_path / "zero.h5")(t=[0.0, 0.5, 1.0], k=1.0)["u"]
    assert np.array_equal(out, np.zeros(3))


# ----------------------------------------------------------------------------------------------
# discretization consistency
# ----------------------------------------------------------------------------------------------
def test_discretization_is_consistent_with_exact_parametric_solution():
    """The nodal exact solution (rank one) leaves a rounding-level residual in the discrete system."""
    problem = load_spec(PROBLEMS / "parametric.yaml")
    disc = discretize(problem)
    assert disc.names == [STATE, "k"]
    t = disc.bases["t"].nodes
    k = disc.bases["k"].nodes
    exact = CPTensor([1.0], [t[1:, None], (10.0 / k - 1.0)[:, None]])  # v = u - 0 on the free time nodes
    assert residual_norm(disc.operator, disc.source, exact) <= 1e-13 * disc.source.norm()
    wrong = CPTensor([1.0], [t[1:, None], (10.0 / k)[:, None]])
    assert residual_norm(disc.operator, disc.source, wrong) >= 1e-3 * disc.source.norm()


# ----------------------------------------------------------------------------------------------
# solver report
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["parametric", "spring", "relaxation"])
def test_solver_report_fields(solved, name):
    result = solved(name)
    problem = load_spec(PROBLEMS / f"{name}.yaml")
    tol = problem.solver.tolerance
    assert isinstance(result, SolveResult)
    assert result.converged is True and result.status == 0
    assert result.message.startswith("converged")
    h = np.asarray(result.residuals)
    assert h[0] == 1.0
    assert np.all(np.diff(h) <= 0.0), h
    rt = result.codebook.report["residual_tolerance"]  # the residual asked by the last enrichment
    assert rt <= tol and result.codebook.report["check_error"] <= tol
    assert h[-1] <= rt and result.residual == h[-1]
    assert np.all(h[:-1] > rt)  # stops at the first mode reaching the residual asked
    assert result.iterations.shape == (h.size - 1,) == (result.n_modes,)
    assert np.all(result.iterations >= 1)
    assert np.all(result.iterations <= problem.solver.max_fixed_point_iterations)
    assert result.wall_time > 0
    report = result.codebook.report
    for key in ("converged", "residual", "residual_history", "iterations", "modes", "wall_time", "tolerance",
                "pgdcli_version"):
        assert key in report, key
    assert report["converged"] is True
    np.testing.assert_array_equal(report["residual_history"], h)
    np.testing.assert_array_equal(report["iterations"], result.iterations)
    assert report["modes"] == result.n_modes
    assert report["tolerance"] == tol
    import pgdcli

    assert report["pgdcli_version"] == pgdcli.__version__


def _solver_space_solution(problem, cb):
    """Rebuild the PGD part (lift removed) of a codebook in the solver's separated coordinates."""
    disc = discretize(problem)
    coords = cb.coordinate_names
    jt = coords.index(disc.time)
    nt = disc.bases[disc.time].nodes.size
    q = len(disc.unknowns)
    weights, state, params = [], [], {c: [] for c in disc.names[1:]}
    for s, u in enumerate(disc.unknowns):
        fm = cb.fields[u]
        lift = disc.lift[u].rank
        time_modes = fm.factors[jt]
        # lift columns are constant in time; PGD columns vanish at t0 (v(t0) = 0)
        assert np.all(time_modes[:, :lift] == 1.0)
        assert np.all(time_modes[0, lift:] == 0.0)
        r = fm.rank - lift
        block = np.zeros((q * (nt - 1), r))
        block[s * (nt - 1):(s + 1) * (nt - 1)] = time_modes[1:, lift:]
        state.append(block)
        weights.append(fm.weights[lift:])
        for c in disc.names[1:]:
            params[c].append(fm.factors[coords.index(c)][:, lift:])
    factors = [np.hstack(state)] + [np.hstack(params[c]) for c in disc.names[1:]]
    return disc, CPTensor(np.concatenate(weights), factors)


def _dense_residual(op, source, approx):
    """||F - A U|| by dense tensors (no orthogonal sweep)."""
    def full(x):
        letters = "abcdefgh"[: x.order]
        return np.einsum(",".join(f"{l}r" for l in letters) + ",r->" + letters, *x.factors, x.weights)

    u = full(approx)
    au = np.zeros(tuple(m.shape[0] for m in op.terms[0]))
    for term in op.terms:
        y = u
        for j, m in enumerate(term):
            y = np.moveaxis(np.tensordot(m, y, axes=(1, j)), 0, j)
        au += y
    return float(np.linalg.norm((full(source) - au).ravel()))


@pytest.mark.parametrize("name", ["parametric", "spring", "relaxation"])
def test_reported_residual_is_honest(solved, name):
    result = solved(name)
    problem = load_spec(PROBLEMS / f"{name}.yaml")
    disc, approx = _solver_space_solution(problem, result.codebook)
    f_norm = disc.source.norm()
    recomputed = residual_norm(disc.operator, disc.source, approx) / f_norm
    assert recomputed == pytest.approx(result.residual, rel=1e-3, abs=1e-14)
    dense = _dense_residual(disc.operator, disc.source, approx) / _dense_residual(
        disc.operator, disc.source, approx.scaled(0.0))
    assert dense == pytest.approx(result.residual, rel=1e-2, abs=1e-14)


def test_update_fallback_reports_the_residual_of_what_it_keeps(monkeypatch):
    # After an enrichment every mode is updated and the residual checked once; if it did not fall,
    # the solver falls back to projecting and updating mode by mode (each update checked with one
    # sweep step from the projection's partial sweeps). Force the fallback at every enrichment and
    # compare the residual it reports with a full orthogonal sweep of the state it leaves.
    from pgdcli.algorithms import enrichment

    checked = []
    one_pass, sweep = enrichment._update_all, enrichment._update_sweep

    def checked_sweep(state, res, suffixes):
        out = sweep(state, res, suffixes)
        checked.append((out, state.residual_norm(), state.source.norm()))
        return out

    monkeypatch.setattr(enrichment, "_update_all", lambda state, previous: one_pass(state, 0.0))
    monkeypatch.setattr(enrichment, "_update_sweep", checked_sweep)
    result = solve_enrichment(load_spec(PROBLEMS / "relaxation.yaml"), 1e-10, 100, None)  # one enrichment
    assert result.converged, result.message
    assert len(checked) == result.n_modes
    for reported, full_sweep, f_norm in checked:
        assert abs(reported - full_sweep) <= 1e-6 * full_sweep + 1e-15 * f_norm


def test_not_converged_when_max_modes_too_small():
    # the enrichment alone (auto would fall back to the tensor-train solver: tests/solve/test_linear_methods.py)
    problem = _variant("spring", {"  tolerance: 1e-10": "  tolerance: 1e-10\n  method: pgd"})
    result = solve(problem, max_modes=2)
    assert result.converged is False
    assert result.status == 1
    assert result.n_modes == 2
    assert result.residual > problem.solver.tolerance
    assert "not converged" in result.message and "max_modes=2" in result.message
    assert result.codebook.report["converged"] is False


def test_callback_sees_every_mode():
    seen = []
    result = solve_enrichment(load_spec(PROBLEMS / "relaxation.yaml"), 1e-4, 100, seen.append)  # one enrichment
    assert [s["mode"] for s in seen] == list(range(1, result.n_modes + 1))
    np.testing.assert_array_equal([s["residual"] for s in seen], result.residuals[1:])
    np.testing.assert_array_equal([s["iterations"] for s in seen], result.iterations)
    assert result.converged and result.residual <= 1e-4


def test_solve_accepts_a_path_and_is_deterministic(solved):
    again = solve(PROBLEMS / "relaxation.yaml")
    first = solved("relaxation").codebook
    for u in first.fields:
        np.testing.assert_array_equal(again.codebook.fields[u].weights, first.fields[u].weights)
        for a, b in zip(again.codebook.fields[u].factors, first.fields[u].factors):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("kwargs,match", [({"tolerance": 0.0}, "tolerance"), ({"tolerance": 1.5}, "tolerance"),
                                          ({"max_modes": 0}, "max_modes")])
def test_solve_rejects_bad_overrides(kwargs, match):
    with pytest.raises(SolverError, match=match):
        solve(load_spec(PROBLEMS / "parametric.yaml"), **kwargs)


def test_solution_codebook_is_a_codebook(solved):
    cb = solved("spring").codebook
    assert isinstance(cb, Codebook)
    assert cb.coordinate_names == ["t", "k", "c"]
    assert cb.unknown_names == ["x", "v"]
    assert [c.role for c in cb.coordinates] == ["time", "parameter", "parameter"]
