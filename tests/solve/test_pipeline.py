"""The solve pipeline (pgdcli.driver): its phases' progress events, the method choice and its fallback rule,
the typed outcome and status, and the report keys each part writes."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import PROBLEMS

import pgdcli
from pgdcli.algorithms.outcome import Learned, SolverOutcome, Status
from pgdcli.driver.method import Method, MethodChoice, Settings
from pgdcli.driver.methods import METHODS, choose_method
from pgdcli.driver.refinement import solve_rounds
from pgdcli.progress import EnrichmentStep, MarchStep, PhaseStarted, ProgressEvent, ReferenceProgress


def _events(name: str) -> tuple[list, object]:
    seen: list = []
    result = pgdcli.solve(pgdcli.load_spec(PROBLEMS / f"{name}.yaml"), callback=seen.append)
    return seen, result


def _phases(seen: list) -> list[str]:
    return [e.what for e in seen if isinstance(e, PhaseStarted)]


def test_a_march_reports_every_phase_and_the_gates_reference():
    seen, result = _events("drag")  # automatic nodes: a pilot march along each parameter, then one solve
    assert result.accurate is True and all(isinstance(e, ProgressEvent) for e in seen)
    assert _phases(seen) == ["solve", "solve", "solve", "refine", "solve", "check"]
    assert seen[0].describe().startswith("method march (equations nonlinear")
    steps = [e for e in seen if isinstance(e, MarchStep)]
    assert steps and steps[-1].fraction() == 1.0 and steps[-1].time == steps[-1].end == 2.0
    # the reference's integration in time, as it goes, between each "check" phase and what follows it
    gate = [e for e in seen if isinstance(e, ReferenceProgress)]
    assert gate and {e.unit for e in gate} == {"time"} and all(0.0 <= e.fraction() <= 1.0 for e in gate)
    assert all(e.phase == "check" for e in gate)
    first_check = [i for i, e in enumerate(seen) if isinstance(e, PhaseStarted) and e.what == "check"][0]
    assert isinstance(seen[first_check + 1], ReferenceProgress)
    k, a = (int(result.codebook.report["resolution_rounds"][-1, i]) for i in (1, 2))  # the nodes it chose
    assert k > 9 and a > 9
    assert f"first nodes from the pilot: k {k}, a {a}" in [e.describe() for e in seen if isinstance(e, PhaseStarted)]


def test_an_enrichment_with_space_reports_the_method_of_lines_per_parameter_point():
    """The gate of a PDE is a method-of-lines solve per parameter point: each one is an event."""
    seen, result = _events("heat1d")
    assert result.accurate is True
    # a smaller residual at the same nodes: the second solve is announced as a refinement of the target
    assert _phases(seen) == ["solve", "solve", "check", "refine", "solve", "check"]
    refine = [e for e in seen if isinstance(e, PhaseStarted) and e.what == "refine"][0]
    assert refine.describe().startswith("the error at the nodes is") and "residual" in refine.describe()
    terms = [e for e in seen if isinstance(e, EnrichmentStep)]
    assert [e.mode for e in terms][:3] == [1, 2, 3] and terms[0].target == 1e-8
    points = [e for e in seen if isinstance(e, ReferenceProgress)]
    assert points and points[-1].done == points[-1].total > 1 and {e.unit for e in points} == {"points"}
    # the same solve again reuses the reference, and its check still reports every point done
    again = [e for e in _events("heat1d")[0] if isinstance(e, ReferenceProgress)]
    assert again and again[-1].done == again[-1].total == points[-1].total


def test_the_method_is_chosen_from_the_equations_and_says_why():
    def choice(name):
        return choose_method(pgdcli.load_spec(PROBLEMS / f"{name}.yaml"))

    # a linear ODE problem: the tensor-train solver when the enrichment stalls, the march when neither meets the
    # tolerance; a linear PDE has no march to fall back to
    assert choice("relaxation").methods == (METHODS["pgd"], METHODS["amen"], METHODS["march"])
    assert choice("relaxation").reason.startswith("a linear problem: the enrichment first")
    assert choice("heat1d").methods == (METHODS["pgd"], METHODS["amen"])
    assert choice("coupled").methods == (METHODS["march"],)
    assert choice("fisher").methods == (METHODS["pde march"],) and "space coordinate" in choice("fisher").reason
    assert all(m.marches for m in (METHODS["march"], METHODS["pde march"])) and not METHODS["pgd"].marches


class _Stalls(Method):
    """A method that gives up at once, as a linear solver whose residual stagnates would."""

    name = "stalling"
    plural = "stalls"

    def __init__(self, placeholder=None):
        self.placeholder = placeholder  # the codebook its outcome holds

    def solve(self, problem, target, settings, learned, callback):
        return SolverOutcome(self.placeholder, Status.STAGNATED, "not converged: stagnated at 0.5", target)

    def stalled(self, outcome):
        return outcome.status is Status.STAGNATED


def test_a_method_that_stalls_falls_back_to_the_next_of_the_choice_and_the_report_says_so():
    problem = pgdcli.load_spec(PROBLEMS / "heat1d.yaml")
    settings = Settings(problem.solver.tolerance, 0.0, problem.solver.max_modes)
    alone, _ = solve_rounds(problem, MethodChoice((METHODS["pgd"],), "test"), settings)
    assert "method_fallback" not in alone.codebook.report
    seen: list = []
    result, _ = solve_rounds(problem, MethodChoice((_Stalls(), METHODS["pgd"]), "test"), settings, seen.append)
    assert result.accurate is True
    assert result.codebook.report["method_fallback"] == "the stalling stopped: stagnated at 0.5; the enrichment ran instead"
    assert result.codebook.report["method"] == "pgd"
    assert "the stalling stopped: stagnated at 0.5; the enrichment runs instead" in [
        e.describe() for e in seen if isinstance(e, PhaseStarted)]
    assert any("the enrichment ran instead (solver.method: auto)" in w for w in result.warnings)
    for u in alone.codebook.fields:  # the same solve, once the stalling method gave up
        np.testing.assert_array_equal(result.codebook.fields[u].weights, alone.codebook.fields[u].weights)
    # without a method to fall back to, the stalled outcome is the result
    failed, _ = solve_rounds(problem, MethodChoice((_Stalls(alone.codebook),), "test"), settings)
    assert failed.status is Status.STAGNATED and not failed.converged and failed.message.endswith("at 0.5")


def test_learned_keeps_the_first_cross_abandoned():
    outcome = SolverOutcome(None, Status.CONVERGED, "converged", 1e-6, cross_abandoned="over budget")
    learned = Learned(target=1e-7).after(outcome)
    assert learned == Learned(target=1e-7, cross_abandoned="over budget")
    assert learned.after(SolverOutcome(None, Status.CONVERGED, "", 1e-6, cross_abandoned="again")) is learned


def test_status_is_an_enum_with_the_persisted_values(solved):
    assert [int(s) for s in Status] == [0, 1, 2, 3, 4]
    assert pgdcli.Status is Status
    result = solved("relaxation")
    assert result.status is Status.CONVERGED and result.status == 0
    assert type(result.codebook.report["status"]) is int  # the file holds the integer


def test_the_check_alone_writes_its_report_keys(solved):
    result = solved("relaxation")
    entries = result.check.report_entries()
    assert set(entries) == {k for k in result.codebook.report if k.startswith("check_")} | {"relative_tolerance"}
    for key, value in entries.items():
        np.testing.assert_array_equal(result.codebook.report[key], value)


@pytest.mark.parametrize("name", ["coupled", "relaxation"])
def test_a_codebook_written_with_the_report_loads_back_the_same(solved, tmp_path, name):
    result = solved(name)
    result.codebook.save(tmp_path / "cb.h5")
    back = pgdcli.Codebook.load(tmp_path / "cb.h5").report
    assert int(back["status"]) == int(result.status) and int(back["accurate"]) == 1
    assert str(back["solver_message"]) == result.codebook.report["solver_message"]
