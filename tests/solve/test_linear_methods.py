"""solver.method for linear problems: the enrichment, the tensor-train solver (amen), and auto's fallback."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import pgdcli
from conftest import PROBLEMS
from pgdcli.algorithms.enrichment import PREDICTION_AFTER, out_of_reach, predicted_modes
from pgdcli.errors import SolverError


def heat1d(method: str = "auto"):
    problem = pgdcli.load_spec(PROBLEMS / "heat1d.yaml")
    return dataclasses.replace(problem, solver=dataclasses.replace(problem.solver, method=method))


def heat1d_error(codebook) -> float:
    """Largest error against the exact exp(-kappa pi^2 t) sin(pi x) at random points and the box's corners."""
    rng = np.random.default_rng(0)
    x, t, kappa = rng.uniform(0, 1, 300), rng.uniform(0, 0.5, 300), rng.uniform(0.1, 1, 300)
    corners = np.array([(a, b, c) for a in (0.0, 0.5) for b in (0.0, 0.5, 1.0) for c in (0.1, 1.0)])
    x, t, kappa = np.concatenate([x, corners[:, 1]]), np.concatenate([t, corners[:, 0]]), \
        np.concatenate([kappa, corners[:, 2]])
    exact = np.exp(-kappa * np.pi ** 2 * t) * np.sin(np.pi * x)
    return float(np.max(np.abs(codebook(x=x, t=t, kappa=kappa)["u"] - exact)))


def test_amen_solves_a_linear_problem_to_its_tolerance():
    result = pgdcli.solve(heat1d("amen"))
    assert result.converged and result.accurate, result.message
    report = result.codebook.report
    assert report["method"] == "amen" and report["method_reason"] == "solver.method: amen"
    assert "tensor-train solver" in report["solver_message"]
    assert heat1d_error(result.codebook) <= 1e-8


def test_auto_falls_back_to_amen_when_the_enrichment_reaches_max_modes():
    result = pgdcli.solve(heat1d(), max_modes=2)
    assert result.converged and result.accurate, result.message
    report = result.codebook.report
    assert report["method"] == "amen"
    assert report["method_reason"].startswith("the enrichment stopped: relative residual")
    assert "max_modes=2" in report["method_reason"] and report["method_reason"].endswith("ran instead")
    assert any("solver.method: auto" in w for w in result.warnings)
    assert heat1d_error(result.codebook) <= 1e-8


def test_auto_runs_the_enrichment_alone_when_it_finishes():
    result = pgdcli.solve(heat1d())
    report = result.codebook.report
    assert result.converged and report["method"] == "pgd"
    assert report["method_reason"].startswith("a linear problem: the enrichment first")
    assert not result.warnings


def test_the_enrichments_advice_works_when_followed():
    refused = pgdcli.solve(heat1d("pgd"), max_modes=2)
    assert not refused.converged
    assert "solver.method: amen" in refused.message
    followed = pgdcli.solve(heat1d("amen"), max_modes=2)
    assert followed.converged and followed.accurate, followed.message
    assert heat1d_error(followed.codebook) <= 1e-8


def test_amen_is_refused_for_nonlinear_equations():
    problem = pgdcli.load_spec(PROBLEMS / "logistic.yaml")
    problem = dataclasses.replace(problem, solver=dataclasses.replace(problem.solver, method="amen"))
    with pytest.raises(SolverError, match="solver.method: 'amen' solves equations linear in the unknowns only"):
        pgdcli.solve(problem)


def test_predicted_modes_extrapolates_the_residuals_decay():
    # a residual falling tenfold every 4 modes from 1: 1e-6 at mode 24
    history = [10.0 ** (-k / 4) for k in range(20)]
    assert predicted_modes(history, 1e-6) == pytest.approx(24.0)
    assert predicted_modes(history, 1e-9) == pytest.approx(36.0)
    assert predicted_modes([1e-3] * 20, 1e-6) == float("inf")  # not falling


def test_out_of_reach_needs_its_prediction_past_the_cap_several_modes_in_a_row():
    falling = [10.0 ** (-k / 10) for k in range(40)]  # a decade every 10 modes: 1e-10 at mode 100
    assert out_of_reach(falling, 2e-11, 100) and not out_of_reach(falling, 2e-10, 100)
    assert not out_of_reach(falling[:PREDICTION_AFTER], 1e-30, 100)  # too few modes to read a rate
    plateau = falling[:30] + [falling[29]] * 12  # flat over the last windows: never, read three times
    assert out_of_reach(plateau, 1e-6, 100)
    spike = falling[:38] + [falling[37], falling[39]]  # one flat mode, then falling again: not three in a row
    assert not out_of_reach(spike, 2e-10, 100)


def test_pgd_solve_and_info_say_which_solver_ran_and_why(tmp_path):
    import json

    from click.testing import CliRunner

    from pgdcli.cli.main import cli

    out = tmp_path / "heat1d.h5"
    runner = CliRunner()
    result = runner.invoke(cli, ["solve", str(PROBLEMS / "heat1d.yaml"), "-o", str(out), "--max-modes", "2",
                                 "--format", "json", "-q"])
    assert result.exit_code == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["method"] == "amen" and "the enrichment stopped" in summary["method_reason"]
    shown = runner.invoke(cli, ["solve", str(PROBLEMS / "heat1d.yaml"), "-o", str(tmp_path / "again.h5"),
                                "--max-modes", "2"])  # with progress and the summary table
    assert shown.exit_code == 0, shown.stderr
    assert "tensor-train solver (amen)" in shown.stderr and "2-norm at the nodes" in shown.stderr
    info = runner.invoke(cli, ["info", str(out)])
    assert info.exit_code == 0, info.stderr
    assert "method: tensor-train solver (amen): the enrichment stopped" in info.stdout


def test_a_tighter_amen_solve_that_stalls_far_below_the_error_at_the_nodes_blames_the_nodes():
    """Error at the nodes 50 x the tolerance with residuals near 1e-9: the discretization's, so more nodes
    (not a refusal naming the solver) even when the tighter solve stalls just short of its target."""
    from types import SimpleNamespace

    from pgdcli.algorithms.outcome import SolverOutcome, Status
    from pgdcli.driver.method import Settings, Try
    from pgdcli.driver.methods import METHODS

    amen = METHODS["amen"]

    def attempt(target, residual, converged):
        status = Status.CONVERGED if converged else Status.STAGNATED
        message = "converged" if converged else "not converged: the residual stopped falling"
        outcome = SolverOutcome(None, status, message, target, "tensor-train solver: residual",
                                residuals=np.array([residual]))
        return Try(target, outcome, SimpleNamespace(node_ratio=50.0, node_error=5e-5))

    tries = [attempt(5e-7, 1.2e-9, True), attempt(1e-9, 1.1e-9, False)]
    assert amen.next_target(None, tries[:1], Settings(1e-6, 0.0, 100)) is not None  # the error asks a tighter one
    kept = amen.keep(tries)
    assert kept.attempt is tries[0] and kept.attempt.outcome.residual == 1.2e-9
    assert kept.stopped is None and kept.limited  # the nodes, not the solver
    entries = amen.round_entries(kept, tries, Settings(1e-6, 0.0, 100))
    assert entries["discretization_limited"] == 1 and "enrichment_stopped" not in entries


def test_a_much_tighter_march_that_left_the_error_as_it_was_is_not_tightened_again():
    """Time nodes a spec fixes across a kink: the error at the nodes is the interpolation's, and a march
    tightened without end would only run into max_steps at a target below rounding."""
    from types import SimpleNamespace

    from pgdcli.algorithms.outcome import SolverOutcome, Status
    from pgdcli.driver.method import Try
    from pgdcli.driver.methods import METHODS, MARCH_SAFETY

    march, settings = METHODS["march"], None

    def attempt(target, ratio):
        outcome = SolverOutcome(None, Status.CONVERGED, "converged", target, "march", residuals=np.array([target]))
        return Try(target, outcome, SimpleNamespace(node_ratio=ratio, coordinate_ratio={}))

    problem = SimpleNamespace(time=None)
    first = attempt(7e-7, 4.5e5)
    assert march.next_target(problem, [first], settings) == pytest.approx(7e-7 * MARCH_SAFETY / 4.5e5)
    assert march.next_target(problem, [first, attempt(1.2e-12, 4.4e5)], settings) is None
    # a tighter march that lowered the error goes on; so does a small step of tightening
    assert march.next_target(problem, [first, attempt(1.2e-12, 40.0)], settings) is not None
    assert march.next_target(problem, [attempt(7e-7, 2.0), attempt(2.8e-7, 1.9)], settings) is not None


def test_a_coefficient_too_large_for_the_enrichment_goes_to_amen(monkeypatch):
    # forced.yaml's sin(w*t) separates into a few Kronecker terms; with the enrichment's cap at one term it
    # is refused with the advice to use amen, and auto follows that advice itself
    from pgdcli.algorithms import enrichment_solve
    from pgdcli.discretization.linear import discretize

    monkeypatch.setattr(enrichment_solve, "discretize", lambda problem, **kw: discretize(problem, max_terms=1, **kw))
    problem = pgdcli.load_spec(PROBLEMS / "forced.yaml")
    enrichment = dataclasses.replace(problem, solver=dataclasses.replace(problem.solver, method="pgd"))
    with pytest.raises(SolverError, match=r"solver.method: amen \(the tensor-train solver\) takes it"):
        pgdcli.solve(enrichment)
    result = pgdcli.solve(problem)
    assert result.converged and result.accurate, result.message
    report = result.codebook.report
    assert report["method"] == "amen" and report["method_reason"].startswith("the enrichment cannot take it")
