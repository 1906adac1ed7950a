"""The error gate and automatic resolution (pgdcli.adapt), on problems written as users write them.

Every accuracy claim is checked against an independent reference: scipy's solve_ivp
(DOP853, rtol = atol = 1e-12), integrated here point by point at 300 random points,
never against the solver's own check.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from click.testing import CliRunner
from threadpoolctl import threadpool_limits

from conftest import spec_text, train_march
import pgdcli
from pgdcli import parse_spec
from pgdcli.adapt import INACCURATE
from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook, InaccurateCodebookWarning

OSCILLATOR = spec_text(
    name=' oscillator',
    coordinates={'t': '{domain: [0, 5]}', 'k': '{domain: [1, 4]}', 'c': '{domain: [0.1, 0.5]}', 'x0': '{domain: [-1, 1]}'},
    unknowns={'x': '{initial: x0}', 'v': '{initial: 0}'},
    equations=['"der(x) = v"', '"der(v) = -k*x - c*v"'],
    solver={'tolerance': '1e-6'},
)

SIR = spec_text(
    name=' sir',
    coordinates={'t': '{domain: [0, 20]}', 'b': '{domain: [0.8, 1.2]}', 'g': '{domain: [0.2, 0.4]}'},
    unknowns={'S': '{initial: 0.99}', 'I': '{initial: 0.01}', 'R': '{initial: 0}'},
    equations=['"der(S) = -b*S*I"', '"der(I) = b*S*I - g*I"', '"der(R) = g*I"'],
    solver={'tolerance': '1e-6'},
)

COARSE = spec_text(
    name=' coarse',
    coordinates={'t': '{domain: [0, 5], nodes: 12}', 'k': '{domain: [1, 4], nodes: 5}'},
    unknowns={'x': '{initial: 1}', 'v': '{initial: 0}'},
    equations=['"der(x) = v"', '"der(v) = -k*x"'],
    solver={'tolerance': '1e-6'},
)


def _max_error_vs_solve_ivp(cb, rhs, initial, n=300, seed=5):
    """Max abs error of the codebook at n random points against solve_ivp trajectories."""
    from scipy.integrate import solve_ivp

    rng = np.random.default_rng(seed)
    params = [c for c in cb.coordinates if c.role != "time"]
    time = next(c for c in cb.coordinates if c.role == "time")
    worst = 0.0
    for _ in range(n):
        p = {c.name: rng.uniform(*c.domain) for c in params}
        t = rng.uniform(*time.domain)
        sol = solve_ivp(lambda s, y: rhs(s, y, p), time.domain, initial(p), method="DOP853", rtol=1e-12,
                        atol=1e-12, t_eval=[t])
        values = cb(**{time.name: t}, **p)
        ref = sol.y[:, 0]
        worst = max(worst, max(abs(float(values[u]) - r) for u, r in zip(cb.unknown_names, ref)))
    return worst


def test_oscillator_without_nodes_meets_its_tolerance():
    result = pgdcli.solve(parse_spec(OSCILLATOR, source="oscillator.yaml"))
    assert result.converged and result.accurate is True, result.message
    cb = result.codebook
    assert cb.report["resolution_auto"] == "t,k,c,x0"
    err = _max_error_vs_solve_ivp(cb, lambda s, y, p: [y[1], -p["k"] * y[0] - p["c"] * y[1]],
                                  lambda p: [p["x0"], 0.0])
    assert err <= 1e-6
    # the measured error in the report agrees with the independent one to within a factor of a few
    assert cb.report["check_error"] <= 1e-6 and err <= 5 * cb.report["check_error"]


def test_sir_without_nodes_meets_its_tolerance():
    result = pgdcli.solve(parse_spec(SIR, source="sir.yaml"))
    assert result.converged and result.accurate is True, result.message
    err = _max_error_vs_solve_ivp(
        result.codebook,
        lambda s, y, p: [-p["b"] * y[0] * y[1], p["b"] * y[0] * y[1] - p["g"] * y[1], p["g"] * y[1]],
        lambda p: [0.99, 0.01, 0.0])
    assert err <= 1e-6


def test_automatic_nodes_grow_where_the_error_is():
    """k moves the oscillation frequency: it is refined; the report says which nodes were tried."""
    result = pgdcli.solve(parse_spec(OSCILLATOR, source="oscillator.yaml"))
    rep = result.codebook.report
    rounds = np.asarray(rep["resolution_rounds"])
    names = result.codebook.coordinate_names
    assert rounds.shape[0] >= 2 and rounds[-1, -1] <= 1.0 < rounds[0, -1]
    assert rounds[-1, names.index("k")] > rounds[0, names.index("k")]
    assert rep["resolution_reason"] == "the measured error meets the tolerance"


def test_under_resolved_explicit_nodes_exit_1_and_write_nothing(tmp_path):
    spec = tmp_path / "coarse.yaml"
    spec.write_text(COARSE)
    out = tmp_path / "coarse.h5"
    res = CliRunner().invoke(cli, ["solve", str(spec), "-o", str(out), "-q"])
    assert res.exit_code == 1
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["coarse.yaml"]
    last = res.stderr.strip().splitlines()[-1]
    assert last.startswith("Error: ") and "tolerance not met: max abs error" in last
    assert "lacks resolution" in last and "no codebook written" in last and "Traceback" not in res.stderr


def test_keep_inaccurate_writes_a_marked_codebook(tmp_path):
    spec = tmp_path / "coarse.yaml"
    spec.write_text(COARSE)
    out = tmp_path / "coarse.h5"
    runner = CliRunner()
    res = runner.invoke(cli, ["solve", str(spec), "-o", str(out), "--keep-inaccurate", "--format", "json", "-q"])
    assert res.exit_code == 1 and out.exists()
    summary = json.loads(res.stdout)
    assert summary["accurate"] is False and summary["converged"] is False and summary["output"] == str(out)
    assert summary["check_error"] > 1e-6
    assert "marked inaccurate" in res.stderr.strip().splitlines()[-1]
    info = json.loads(runner.invoke(cli, ["info", str(out), "--format", "json"]).stdout)
    assert info["accurate"] is False and info["check"]["error"] == summary["check_error"]
    assert "INACCURATE" in runner.invoke(cli, ["info", str(out)]).stdout
    with pytest.warns(InaccurateCodebookWarning, match="misses its tolerance"):
        Codebook.load(out)


def test_an_accurate_codebook_loads_without_warning(tmp_path):
    result = pgdcli.solve(parse_spec(COARSE.replace("nodes: 12", "nodes: auto").replace("nodes: 5", "nodes: auto"),
                                     source="fine.yaml"))
    assert result.accurate is True, result.message
    path = result.codebook.save(tmp_path / "fine.h5")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cb = Codebook.load(path)
    assert cb.accurate is True and cb.info()["accurate"] is True


DECAY = spec_text(
    name=' decay',
    coordinates={'t': '{domain: [0, 1], nodes: 8}', 'k': '{domain: [0.5, 2], nodes: 5}'},
    unknowns={'u': '{initial: 1}'},
    equations=['"der(u) = -k*u"'],
    solver={'tolerance': '1e-9'},
)


def test_relative_tolerance_relaxes_the_bound_where_the_solution_is_large():
    """error <= atol + rtol |u|: a coarse codebook that fails atol alone passes with a relative part."""
    from pgdcli.checks import check

    problem = parse_spec(DECAY, source="decay.yaml")
    strict = pgdcli.solve(problem)
    assert strict.status == INACCURATE
    relative = check.check_codebook(problem, strict.codebook, tolerance=1e-300, relative_tolerance=1.0).ratio
    assert 1e-9 < relative < 0.1  # max |u - u_ref| / |u_ref| over the sample
    loose = pgdcli.solve(problem, relative_tolerance=2 * relative)
    assert loose.accurate is True and loose.codebook.report["relative_tolerance"] == 2 * relative
    assert loose.check.ratio <= 1.0 < loose.check.error / 1e-9
    tighter = pgdcli.solve(problem, relative_tolerance=0.25 * relative)
    assert tighter.status == INACCURATE  # the relative part is checked too


def test_max_nodes_reached_is_an_honest_refusal():
    text = spec_text(OSCILLATOR, solver={"tolerance": "1e-6", "max_nodes": "9"})
    result = pgdcli.solve(parse_spec(text, source="capped.yaml"))
    assert result.status == INACCURATE and result.accurate is False
    assert "solver.max_nodes = 9" in result.message and "lacks resolution" in result.message


RUNGE = spec_text(
    name=' runge',
    coordinates={'t': '{domain: [0, 1]}', 'p': '{domain: [0, 1]}'},
    unknowns={'u': '{initial: "1/(1 + 400*(p - 0.3)**2)"}'},
    equations=['"der(u) = -u"'],
    solver={'tolerance': '1e-6'},
)


def test_a_sharp_feature_in_a_parameter_gets_elements_where_it_is():
    """Runge's function in p: doubling the nodes converges slowly, so p is split into elements near 0.3."""
    result = pgdcli.solve(parse_spec(RUNGE, source="runge.yaml"))
    assert result.accurate is True, result.message
    cb = result.codebook
    bp = np.asarray(cb.coordinate("p").breakpoints)
    assert bp.size > 3 and cb.report["resolution_elements"] == f"p:{bp.size - 1}"
    widths = np.diff(bp)
    at_feature = np.searchsorted(bp, 0.3, side="right") - 1
    assert widths[at_feature] < widths.max()  # the element at the feature is among the smaller ones
    rng = np.random.default_rng(1)
    t, p = rng.uniform(0, 1, 3000), rng.uniform(0, 1, 3000)
    assert np.abs(cb(t=t, p=p)["u"] - np.exp(-t) / (1 + 400 * (p - 0.3) ** 2)).max() <= 1e-6


def test_explicit_elements_are_kept_and_saved(tmp_path):
    text = RUNGE.replace("p: {domain: [0, 1]}", "p: {domain: [0, 1], nodes: 17, elements: 16}").replace(
        "t: {domain: [0, 1]}", "t: {domain: [0, 1], nodes: 33}")
    result = pgdcli.solve(parse_spec(text, source="runge16.yaml"))
    assert result.accurate is True, result.message
    assert result.codebook.report["resolution_rounds"].shape[0] == 1  # explicit nodes: checked, not changed
    cb = Codebook.load(result.codebook.save(tmp_path / "runge16.h5"))
    assert cb.coordinate("p").breakpoints == tuple(np.linspace(0, 1, 17)) and cb.coordinate("p").nodes == 16 * 16 + 1
    t, p = np.random.default_rng(2).uniform(0, 1, (2, 500))
    assert np.abs(cb(t=t, p=p)["u"] - np.exp(-t) / (1 + 400 * (p - 0.3) ** 2)).max() <= 1e-6


def test_elements_only_for_chebyshev_parameters():
    from pgdcli.errors import SpecError

    with pytest.raises(SpecError, match=r"coordinates\.t\.elements: elements are for chebyshev parameter"):
        parse_spec(RUNGE.replace("t: {domain: [0, 1]}", "t: {domain: [0, 1], elements: 2}"), source="x.yaml")
    with pytest.raises(SpecError, match=r"coordinates\.p\.elements: elements are for chebyshev parameter"):
        parse_spec(RUNGE.replace("p: {domain: [0, 1]}", "p: {domain: [0, 1], elements: 2, discretization: linear}"),
                   source="x.yaml")


def _without_nodes(name: str) -> str:
    import yaml

    from conftest import PROBLEMS

    data = yaml.safe_load((PROBLEMS / f"{name}.yaml").read_text())
    for body in data["coordinates"].values():
        body.pop("nodes", None)
    return yaml.safe_dump(data, sort_keys=False)


def _exact(name):
    from conftest import EXACT

    if name in EXACT:
        return EXACT[name]
    if name == "logistic":
        return lambda p: {"u": p["u0"] * np.exp(p["r"] * p["t"]) / (1 - p["u0"] + p["u0"] * np.exp(p["r"] * p["t"]))}
    return lambda p: {"u": np.exp(-p["kappa"] * np.pi**2 * p["t"]) * np.sin(np.pi * p["x"])}  # heat1d


@pytest.mark.parametrize("name", ["parametric", "spring", "relaxation", "logistic", "heat1d"])
def test_shipped_problems_solve_without_nodes_at_their_tolerance(name):
    from conftest import codebook_points, max_abs_error

    problem = parse_spec(_without_nodes(name), source=f"{name}-auto.yaml")
    result = pgdcli.solve(problem)
    assert result.accurate is True, result.message
    errors = max_abs_error(result.codebook, _exact(name), codebook_points(result.codebook, 300, 3))
    assert max(errors.values()) <= problem.solver.tolerance


def test_coupled_without_nodes_against_solve_ivp():
    result = pgdcli.solve(parse_spec(_without_nodes("coupled"), source="coupled-auto.yaml"))
    assert result.accurate is True, result.message
    err = _max_error_vs_solve_ivp(result.codebook, lambda s, y, p: [1 - y[1] * y[2], 2 - y[0] * y[2], 3 - y[0] * y[1]],
                                  lambda p: [p["a"], p["b"], p["c"]], n=100)
    assert err <= 1e-9


@pytest.mark.slow
def test_poisson_without_nodes_meets_its_tolerance():
    result = pgdcli.solve(parse_spec(_without_nodes("poisson"), source="poisson-auto.yaml"))
    assert result.accurate is True, result.message
    assert result.check.error <= 1e-9


def test_measured_error_agrees_with_an_independent_verify():
    """The report's measured error and pgd verify's (another sample: Sobol points, random times) agree."""
    result = pgdcli.solve(parse_spec(OSCILLATOR, source="oscillator.yaml"))
    measured = result.codebook.report["check_error"]
    report = pgdcli.verify(result.codebook, samples=64, seed=3)
    verified = max(e.max_abs_error for e in report.unknowns.values())
    assert verified <= 1e-6 and measured <= 1e-6
    assert measured / 4 <= verified <= 4 * measured


@pytest.mark.slow
def test_rigid_body_without_nodes_meets_its_tolerance():
    """The 7-D shipped problem with every node count left to the solver (~1 min)."""
    result = pgdcli.solve(parse_spec(_without_nodes("rigid_body"), source="rigid_body-auto.yaml"))
    assert result.accurate is True, result.message
    report = pgdcli.verify(result.codebook, samples=64, seed=4, max_corners=32)
    assert max(e.max_abs_error for e in report.unknowns.values()) <= 1e-5


def test_query_of_an_inaccurate_codebook_warns_in_one_line(tmp_path):
    import subprocess
    import sys

    spec = tmp_path / "coarse.yaml"
    spec.write_text(COARSE)
    out = tmp_path / "coarse.h5"
    CliRunner().invoke(cli, ["solve", str(spec), "-o", str(out), "--keep-inaccurate", "-q"])
    res = subprocess.run([sys.executable, "-c", "from pgdcli.cli.entry import main; main()", "query", str(out),
                          "--t", "1", "--k", "2"], capture_output=True, text=True)
    assert res.returncode == 0 and len(res.stdout.split()) == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Warning: ") and "misses its tolerance" in lines[0]


def test_pde_check_reuses_its_reference_for_the_same_nodes(monkeypatch):
    """An enrichment retried on the same nodes is checked against the same reference, computed once;
    the codebook's values at the report's points are verify's own."""
    from conftest import PROBLEMS

    from pgdcli.checks import check

    calls = []
    real = check.verify

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(check, "verify", counted)  # the name the check calls
    check._PDE_REFERENCES.clear()
    result = pgdcli.solve(pgdcli.load_spec(PROBLEMS / "heat1d.yaml"))
    assert result.accurate is True and result.codebook.report["enrichment_attempts"].shape[0] == 2
    assert len(calls) == 1  # two enrichments, one reference
    report = real(result.codebook, samples=check.PDE_SAMPLES, times=check.PDE_TIMES, max_corners=check.PDE_CORNERS,
                  jobs=1, rtol=1e-12, atol=1e-12)
    values = check.on_report_grid(result.codebook, report)
    np.testing.assert_array_equal(values["u"], report.codebook_values["u"])


def test_solve_json_and_info_report_the_same_nodes_chosen(tmp_path):
    spec = tmp_path / "osc.yaml"
    spec.write_text(OSCILLATOR)
    out = tmp_path / "osc.h5"
    runner = CliRunner()
    res = runner.invoke(cli, ["solve", str(spec), "-o", str(out), "--format", "json", "-q"])
    assert res.exit_code == 0, res.output
    chosen = json.loads(res.stdout)["resolution"]
    info = json.loads(runner.invoke(cli, ["info", str(out), "--format", "json"]).stdout)
    assert chosen == info["nodes_chosen"] and chosen["automatic"] == ["t", "k", "c", "x0"]
    assert chosen["rounds"][-1]["ratio"] <= 1.0 < chosen["rounds"][0]["ratio"]
    text = runner.invoke(cli, ["info", str(out)]).stdout
    k = " -> ".join(str(r["nodes"]["k"]) for r in chosen["rounds"])
    assert f"k: {k}" in text
    # the check's parts: the same in both, per coordinate as the codebook's report holds them
    solved = json.loads(res.stdout)
    rep = Codebook.load(out).report
    ratios = dict(zip(str(rep["check_coordinates"]).split(","), np.atleast_1d(rep["check_coordinate_ratio"]).tolist()))
    assert solved["check_coordinate_ratio"] == info["check"]["coordinate_ratio"] == ratios
    assert set(ratios) == {"t", "k", "c", "x0"}
    assert solved["check_node_error"] == info["check"]["node_error"] <= solved["check_error"]


def test_codebook_at_a_steady_report_grid_is_verifys_own():
    """A steady problem (no time axis in the report): the values at the report's points are verify's."""
    from conftest import PROBLEMS

    from pgdcli.checks import check

    result = pgdcli.solve(pgdcli.load_spec(PROBLEMS / "poisson.yaml"))
    report = pgdcli.verify(result.codebook, samples=check.PDE_SAMPLES, times=check.PDE_TIMES,
                           max_corners=check.PDE_CORNERS, jobs=1, rtol=1e-12, atol=1e-12)
    assert report.time is None and report.codebook_values["u"].ndim == 3  # (S, X, Y)
    np.testing.assert_array_equal(check.on_report_grid(result.codebook, report)["u"], report.codebook_values["u"])



def test_a_second_march_starts_from_the_target_learned():
    """The RMS target that met the tolerance at the nodes is carried to the next solve (the next
    round of the automatic resolution) instead of being found again by a second march."""
    from pathlib import Path

    from pgdcli.driver.method import Settings
    from pgdcli.driver.methods import CHECK_FIRST, choose_method
    from pgdcli.driver.refinement import solve_rounds

    text = (Path(__file__).resolve().parents[1] / "user_problems" / "sir.yaml").read_text()
    for name in ("t", "b", "g", "I0"):  # a coarse grid: the march's own error at the nodes decides
        text = text.replace(f"  {name}: {{domain:", f"  {name}: {{nodes: 9, domain:")
    problem = parse_spec(text, source="sir.yaml")
    settings = Settings(1e-6, 0.0, problem.solver.max_modes)
    # as pgdcli.solve runs it (two BLAS threads per xdist worker: 10x slower); the train march, whose RMS
    # target needs a second march on this grid (the grid march meets it in one)
    with threadpool_limits(1), train_march():
        first, learned = solve_rounds(problem, choose_method(problem), settings)
        second, _ = solve_rounds(problem, choose_method(problem), settings, learned=learned)
    attempts = first.codebook.report["march_attempts"]
    assert attempts.shape[0] >= 2 and attempts[0, 0] == CHECK_FIRST * 1e-6  # it had to tighten
    assert first.check.node_ratio <= 1.0 and learned.target == attempts[-1, 0]
    assert second.codebook.report["march_attempts"].tolist() == [[attempts[-1, 0], second.check.error]]
    assert second.check.node_ratio <= 1.0


def test_a_second_enrichment_starts_from_the_residual_learned():
    """heat1d needs a residual a decade below its tolerance: found once, then carried to the next solve."""
    from conftest import PROBLEMS

    from pgdcli.driver.method import Settings
    from pgdcli.driver.methods import choose_method
    from pgdcli.driver.refinement import solve_rounds

    problem = pgdcli.load_spec(PROBLEMS / "heat1d.yaml")
    opts = problem.solver
    settings = Settings(opts.tolerance, 0.0, opts.max_modes)
    with threadpool_limits(1):  # as pgdcli.solve runs it
        first, learned = solve_rounds(problem, choose_method(problem), settings)
        second, _ = solve_rounds(problem, choose_method(problem), settings, learned=learned)
    attempts = first.codebook.report["enrichment_attempts"]
    assert attempts.shape[0] == 2 and attempts[0, 0] == opts.tolerance
    assert learned.target == attempts[-1, 0] < opts.tolerance
    assert second.codebook.report["enrichment_attempts"][:, 0].tolist() == [learned.target]
    assert second.accurate is not False and second.check.node_ratio <= 1.0


def test_an_enrichment_stopped_by_max_modes_is_named_not_blamed_on_nodes():
    """The first solve meets its residual in 30 modes; the smaller residual the error at the nodes asks
    for needs more. The refusal names max_modes; only k, whose error between nodes is large, is refined
    (before, time was refined to the cap and blamed)."""
    with threadpool_limits(1):
        result = pgdcli.solve(parse_spec(OSCILLATOR + "  max_modes: 30\n  method: pgd\n", source="capped.yaml"))
    assert result.status == INACCURATE and result.accurate is False
    assert "enrichment could not lower its residual further" in result.message
    assert "raise solver.max_modes" in result.message
    rounds = result.codebook.report["resolution_rounds"]  # (rounds, t k c x0 + ratio)
    assert np.all(rounds[:, 0] == rounds[0, 0])  # the time nodes were not refined for the enrichment's error
    with threadpool_limits(1):
        enough = pgdcli.solve(parse_spec(OSCILLATOR + "  max_modes: 60\n  method: pgd\n", source="enough.yaml"))
    assert enough.accurate is True
    assert "or solver.method: amen" in result.message  # the other advice works too
    with threadpool_limits(1):
        other = pgdcli.solve(parse_spec(OSCILLATOR + "  max_modes: 34\n  method: amen\n", source="amen.yaml"))
    assert other.accurate is True and other.codebook.report["method"] == "amen"


@pytest.mark.parametrize("measured,tail,says", [
    (2.0, 7.3, "its Chebyshev tail estimates an error between its nodes of 7.3 x the tolerance"),
    (7.3, 2.0, "error between its nodes 7.3 x the tolerance"),
])
def test_a_refusal_says_whether_a_coordinates_error_was_measured_or_estimated(measured, tail, says):
    """The larger of the error measured off the coordinate's nodes and its Chebyshev tail is quoted, as what it is
    (a 7-coordinate kinetics model's refusal quoted its tail, 7.3x, as the error between its nodes)."""
    from pgdcli.adapt import refusal
    from pgdcli.checks.check import CheckResult

    problem = parse_spec(COARSE, source="coarse.yaml")
    check = CheckResult(4e-6, 1e-7, 4e-6, 200, 0, {}, {}, ratio=4.0, node_ratio=0.1, between_ratio=4.0,
                        coordinate_ratio={"t": 0.1, "k": measured}, tail_ratio={"k": tail}, tolerance=1e-6,
                        method="DOP853")
    text = refusal(problem, check, True)
    assert text == f"coordinate 'k' lacks resolution ({says}; it has nodes: 5; add nodes or write 'nodes: auto')"
