"""The march's tolerance as a checked bound: pgdcli.checks.check and the retry loop in pgdcli.solve.

The measured error is checked against exact solutions (never against itself), and
the shipped nonlinear problems' codebooks against the tolerance of their specs at
an independent sample (pgd verify's Sobol points, random times).
"""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from conftest import PROBLEMS, spec_text, train_march

import pgdcli
from pgdcli import load_spec, parse_spec
from pgdcli.checks import check, sampling
from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook, TT
from pgdcli.driver.methods import MARCH_SAFETY


def exact_logistic(t, r, u0):
    e = np.exp(r * t)
    return u0 * e / (1.0 - u0 + u0 * e)


def _variant(name: str, edit) -> str:
    data = yaml.safe_load((PROBLEMS / f"{name}.yaml").read_text())
    edit(data)
    return yaml.safe_dump(data, sort_keys=False)


def test_sample_holds_every_corner_grid_nodes_and_points_between(solved):
    cb = solved("coupled").codebook
    problem = load_spec(PROBLEMS / "coupled.yaml")
    points, at_nodes = sampling.check_sample(problem, cb)
    names = ["a", "b", "c"]
    grid = {n: cb.coordinate(n).basis().nodes for n in names}
    on_grid = np.all([np.isin(points[n], grid[n]) for n in names], axis=0)
    np.testing.assert_array_equal(on_grid, at_nodes)  # node points are nodes, the others are not
    assert (~at_nodes).sum() == sampling.BETWEEN
    corners = {tuple(c) for c in itertools.product((0.0, 1.0), repeat=3)}
    found = {tuple(float(points[n][i]) for n in names) for i in np.flatnonzero(at_nodes)}
    assert corners <= found
    for n in names:
        assert points[n].min() >= 0.0 and points[n].max() <= 1.0


def test_sample_has_every_corner_within_the_budget_and_a_subset_beyond(solved, monkeypatch):
    cb = solved("rigid_body").codebook
    problem = load_spec(PROBLEMS / "rigid_body.yaml")
    names = [c.name for c in problem.parameter_coordinates]

    def corners() -> np.ndarray:
        points, at_nodes = sampling.check_sample(problem, cb)
        box = np.column_stack([points[n][at_nodes] for n in names])
        return np.unique(box[np.all((box == 0.5) | (box == 1.5), axis=1)], axis=0)

    assert sampling.CORNERS == sampling.MAX_CORNERS  # the gate sees the corners pgd verify sees
    assert len(corners()) == 64  # all of a 6-D box's, besides face points
    monkeypatch.setattr(sampling, "CORNERS", 16)
    assert 16 <= len(corners()) < 64  # a seeded subset (face points may land on more corners)


@pytest.mark.parametrize("name,limit", [("coupled", 64), ("rigid_body", 64), ("rigid_body", 8)])
def test_lines_run_off_the_nodes_of_each_coordinate_from_every_corner_of_the_others(solved, monkeypatch, name,
                                                                                      limit):
    """Per coordinate, one point off its nodes from each corner of the other coordinates' box (a subset
    of CORNER_LINES beyond): where an unseen SEIRS model's interpolation error in E0 peaked."""
    monkeypatch.setattr(sampling, "CORNER_LINES", limit)
    cb = solved(name).codebook
    problem = load_spec(PROBLEMS / f"{name}.yaml")
    names = [c.name for c in problem.parameter_coordinates]
    points, line = sampling.line_sample(problem, cb)
    for j, n in enumerate(names):
        others = [o for o in names if o != n]
        rows = line == j
        off = ~np.isin(points[n][rows], cb.coordinate(n).basis().nodes)
        assert off.all()  # every point of the coordinate's line is off its nodes
        ends = np.column_stack([np.isin(points[o][rows], problem.coordinate(o).domain) for o in others])
        at_corner = np.column_stack([points[o][rows] for o in others])[ends.all(axis=1)]
        corners = {tuple(c) for c in at_corner}
        assert len(corners) >= min(2 ** len(others), limit)  # all corners of the others, or a subset of `limit`
        if 2 ** len(others) > limit:
            assert len(corners) <= limit + sampling.LINE  # the random lines may land on a few corners too


def test_measured_error_is_the_true_error_of_the_codebook(solved):
    """check_codebook against the exact logistic solution at the same points and times."""
    result = solved("logistic")
    cb = result.codebook
    problem = load_spec(PROBLEMS / "logistic.yaml")
    measured = check.check_codebook(problem, cb)
    points, _ = sampling.check_sample(problem, cb)
    lines, _ = sampling.line_sample(problem, cb)
    points = {n: np.concatenate([points[n], lines[n]]) for n in points}
    nodes = cb.coordinate("t").basis().nodes
    times = np.concatenate([nodes, 0.5 * (nodes[1:] + nodes[:-1])])  # the nodes and the midpoints between
    values = cb(t=times[None, :], r=points["r"][:, None], u0=points["u0"][:, None])["u"]
    true = np.abs(values - exact_logistic(times[None, :], points["r"][:, None], points["u0"][:, None]))
    assert true.max() > 1e-13  # not a codebook exact to rounding: the comparison can fail
    assert measured.error == pytest.approx(true.max(), rel=1e-2, abs=1e-12)
    assert measured.ratio == pytest.approx(measured.error / problem.solver.tolerance)
    assert measured.points == points["r"].size and measured.failed == 0


def test_a_wrong_codebook_is_measured_wrong(solved):
    cb = solved("logistic").codebook
    problem = load_spec(PROBLEMS / "logistic.yaml")
    fm = cb.fields["u"]
    cores = list(fm.cores)
    cores[-1] = cores[-1] * (1.0 + 1e-4)  # the whole field 1e-4 too large
    wrong = Codebook(cb.coordinates, {"u": TT(tuple(cores), fm.mode_order)}, name="wrong")
    measured = check.check_codebook(problem, wrong)
    points, _ = sampling.check_sample(problem, cb)
    t = cb.coordinate("t").basis().nodes
    expected = 1e-4 * exact_logistic(t[None, :], points["r"][:, None], points["u0"][:, None]).max()
    assert measured.error == pytest.approx(expected, rel=1e-3)


def test_report_states_the_measured_error(solved):
    result = solved("coupled")
    rep = result.codebook.report
    tol = rep["tolerance"]
    assert 0.0 < rep["check_error"] <= tol
    assert rep["check_points"] > 100 and rep["check_failed"] == 0
    assert rep["check_error"] == max(rep["check_node_error"], rep["check_between_error"])
    assert f"max abs error {rep['check_error']:.3g} at {rep['check_points']} check points" in result.message
    assert rep["march_attempts"].shape[1] == 2


def _logistic_with_first_check(monkeypatch, tamper) -> tuple[list, object]:
    """Solve logistic at 1e-8 with ``tamper(out, problem)`` applied to the first check's result only."""
    real = check.check_codebook
    calls = []

    def fake(problem, codebook, **kw):
        out = real(problem, codebook, **kw)
        calls.append(codebook.report["tolerance"])
        if len(calls) == 1:
            tamper(out, problem)
        return out

    monkeypatch.setattr(check, "check_codebook", fake)
    text = _variant("logistic", lambda d: d["solver"].update(tolerance=1e-8))
    return calls, pgdcli.solve(parse_spec(text, source="logistic-check.yaml"))


def test_march_is_tightened_when_the_error_between_time_nodes_exceeds(monkeypatch):
    """At the nodes within the tolerance, 2x between the time nodes (the march's slabs): a tighter march."""
    def tamper(out, problem):
        out.coordinate_ratio = {**out.coordinate_ratio, problem.time: 2.0}
        out.error = out.between_error = 2.0 * problem.solver.tolerance
        out.ratio = 2.0

    calls, result = _logistic_with_first_check(monkeypatch, tamper)
    assert len(calls) == 2
    assert calls[1] == pytest.approx(calls[0] * MARCH_SAFETY / 2.0)
    assert result.codebook.report["check_error"] <= 1e-8 and not result.warnings


def test_march_is_tightened_until_the_check_passes(monkeypatch):
    """The first check reports 4x the tolerance at the nodes: the march is repeated with a tighter target."""
    def tamper(out, problem):
        out.error = out.node_error = 4.0 * problem.solver.tolerance
        out.ratio = out.node_ratio = 4.0

    calls, result = _logistic_with_first_check(monkeypatch, tamper)
    rep = result.codebook.report
    assert len(calls) == 2
    assert calls[1] == pytest.approx(calls[0] * MARCH_SAFETY / 4.0)
    assert rep["march_tolerance"] == pytest.approx(calls[1]) and rep["tolerance"] == 1e-8
    np.testing.assert_allclose(rep["march_attempts"][:, 0], calls)
    assert "rejected), 2 marches, max abs error" in result.message and rep["check_error"] <= 1e-8
    assert not result.warnings


def test_error_between_nodes_asks_for_nodes_not_a_tighter_march():
    """Too few nodes in r: the nodes are right, the interpolation is not; one march, refused naming r."""
    from pgdcli.adapt import INACCURATE

    text = _variant("logistic", lambda d: d["coordinates"]["r"].update(nodes=6))
    result = pgdcli.solve(parse_spec(text, source="logistic-coarse.yaml"))
    rep = result.codebook.report
    assert rep["march_attempts"].shape[0] == 1
    assert rep["check_node_error"] <= 1e-10 < rep["check_between_error"]
    assert result.status == INACCURATE and not result.converged and result.accurate is False
    assert "coordinate 'r' lacks resolution" in result.message and "it has nodes: 6" in result.message
    # the message's number is the true error: the exact solution at the reported place
    where = dict(kv.split("=") for kv in rep["check_where"].split(", "))
    p = {k: float(v) for k, v in where.items()}
    true = abs(result.codebook(**p)["u"] - exact_logistic(p["t"], p["r"], p["u0"]))
    assert true == pytest.approx(rep["check_between_error"], rel=1e-6)
    assert f"max abs error {true:.3g}" in result.message


def test_solve_and_info_print_the_measured_error(tmp_path):
    out = tmp_path / "logistic.h5"
    runner = CliRunner()
    with train_march():  # the rounding counts of the tensor-train march
        res = runner.invoke(cli, ["solve", str(PROBLEMS / "logistic.yaml"), "-o", str(out), "--format", "json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    cb = Codebook.load(out)
    assert summary["check_error"] == cb.report["check_error"] <= 1e-10
    info = runner.invoke(cli, ["info", str(out), "--format", "json"])
    data = json.loads(info.stdout)
    assert data["check"]["error"] == cb.report["check_error"]
    assert data["check"]["points"] == cb.report["check_points"]
    assert data["roundings"] == {k: cb.report[f"roundings_{k}"] for k in ("exact", "sketched", "redone")}
    assert data["roundings"]["exact"] > 0
    text = runner.invoke(cli, ["info", str(out)])
    r = data["roundings"]
    assert f"tensor-train roundings: {r['exact']} exact, {r['sketched']} randomized" in text.stdout
    assert f"max error: {cb.report['check_error']:.3e} at {cb.report['check_points']} check points" in text.stdout


def test_march_without_parameters_checks_its_one_point():
    text = spec_text(
        name=' single',
        coordinates={'t': '{domain: [0, 2], nodes: 8}'},
        unknowns={'u': '{initial: 0.3}'},
        equations=['"der(u) = 1.5*u*(1 - u)"'],
        solver={'tolerance': '1e-10'},
    )
    result = pgdcli.solve(parse_spec(text, source="single.yaml"))
    rep = result.codebook.report
    assert rep["check_points"] == 1 and "at 1 check point against scipy" in result.message
    t = result.codebook.coordinate("t").basis().nodes
    true = np.abs(result.codebook(t=t)["u"] - exact_logistic(t, 1.5, 0.3)).max()
    assert rep["check_error"] == pytest.approx(true, rel=1e-2, abs=1e-13) and true <= 1e-10


def test_a_second_check_at_the_same_sample_reuses_the_reference(solved, monkeypatch):
    """A solve retried at the same nodes is checked at the same sample: one integration, the same numbers,
    and a different codebook still measured by its own values."""
    cb = solved("logistic").codebook
    problem = load_spec(PROBLEMS / "logistic.yaml")
    calls = []
    integrate = check._integrate_reference
    monkeypatch.setattr(check, "_integrate_reference", lambda *a, **k: calls.append(1) or integrate(*a, **k))
    monkeypatch.setattr(check, "_ODE_REFERENCES", {})
    first = check.check_codebook(problem, cb)
    fm = cb.fields["u"]
    wrong = Codebook(cb.coordinates, {"u": TT((*fm.cores[:-1], fm.cores[-1] * (1.0 + 1e-4)), fm.mode_order)})
    second = check.check_codebook(problem, wrong)
    seen = []
    again = check.check_codebook(problem, cb, progress=seen.append)
    assert len(calls) == 1
    assert len(seen) == 1 and seen[0].fraction() == 1.0 and seen[0].unit == "time"  # a progress bar still ends
    assert again.error == first.error and again.ratio == first.ratio
    assert second.error > 1e3 * first.error
    check.check_codebook(problem, cb, seed=1)  # another sample: integrated
    assert len(calls) == 2


def test_a_march_the_reference_cannot_check_says_so(monkeypatch, tmp_path):
    """If scipy cannot integrate the problem the march stands, unchecked, and says so everywhere."""
    from pgdcli.errors import PgdError

    def refuse(problem, codebook, **kw):
        raise PgdError("equations[0]: not for the reference")

    monkeypatch.setattr(check, "check_codebook", refuse)
    out = tmp_path / "logistic.h5"
    res = CliRunner().invoke(cli, ["solve", str(PROBLEMS / "logistic.yaml"), "-o", str(out), "--format", "json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)  # valid JSON: no NaN
    assert summary["check_error"] is None and "not checked against scipy" in summary["message"]
    assert any("could not be checked against scipy: equations[0]: not for the reference" in w
               for w in summary["warnings"])
    info = json.loads(CliRunner().invoke(cli, ["info", str(out), "--format", "json"]).stdout)
    assert info["check"]["error"] is None and info["check"]["points"] == 0
    assert "max error" not in CliRunner().invoke(cli, ["info", str(out)]).stdout


def test_error_and_ratio_leaves_out_failed_samples_in_every_shape():
    """One comparison for the ODE check (S, T) and the PDE check (S, T, X): a sample whose reference failed
    (its values NaN or arbitrary) counts as error 0, not as the codebook's value (the PDE check did that)."""
    from pgdcli.checks.check import error_and_ratio

    ref = {"u": np.array([[[1.0, 2.0]], [[np.nan, np.nan]], [[3.0, -4.0]]])}  # (S=3, T=1, X=2)
    approx = {"u": np.array([[[1.1, 2.0]], [[50.0, 50.0]], [[3.0, -4.4]]])}
    ok = np.array([True, False, True])
    err, ratio, per_unknown = error_and_ratio(ref, approx, ok, 0.1, 0.1)
    np.testing.assert_allclose(err[:, 0], [[0.1, 0.0], [0.0, 0.0], [0.0, 0.4]], atol=1e-12)
    np.testing.assert_allclose(ratio[2, 0, 1], 0.4 / (0.1 + 0.1 * 4.0))
    assert per_unknown == {"u": pytest.approx(0.4)}
    err2, _, per2 = error_and_ratio({"u": ref["u"][:, 0, :]}, {"u": approx["u"][:, 0, :]}, ok, 0.1, 0.0)
    np.testing.assert_allclose(err2, err[:, 0])
    _, _, none = error_and_ratio(ref, approx, np.zeros(3, bool), 0.1, 0.0)
    assert np.isnan(none["u"])


def test_checked_time_nodes_are_all_of_them_or_every_kth_and_the_last():
    from pgdcli.checks.sampling import CHECK_TIME_NODES, checked_time_nodes

    few = np.linspace(0.0, 1.0, CHECK_TIME_NODES)
    picked, stride = checked_time_nodes(few)
    assert stride == 1 and np.array_equal(picked, np.arange(few.size))
    for n in (CHECK_TIME_NODES + 1, 24481, 100003):
        picked, stride = checked_time_nodes(np.linspace(0.0, 1.0, n))
        assert picked[0] == 0 and picked[-1] == n - 1 and picked.size <= CHECK_TIME_NODES + 1
        assert np.all(np.diff(picked)[:-1] == stride) and 0 < np.diff(picked)[-1] <= stride


@pytest.mark.parametrize("n,text", [(1, "1st"), (2, "2nd"), (3, "3rd"), (4, "4th"), (11, "11th"), (12, "12th"),
                                    (13, "13th"), (21, "21st"), (22, "22nd"), (101, "101st"), (111, "111th")])
def test_ordinal_of_a_time_node_stride(n, text):
    assert check.ordinal(n) == text
