"""Nonlinear problems through the separated time march (pgdcli.algorithms.march).

References are independent of pgdcli: scipy's solve_ivp (DOP853, rtol = atol =
1e-12) for the coupled system, the closed form for the logistic and
relaxation equations. Each expensive solve runs once per module.
"""

from __future__ import annotations

import itertools
import json
import re

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from conftest import PROBLEMS, assert_solved, spec_text, train_march
from scipy.integrate import solve_ivp

import pgdcli
from pgdcli import load_spec, parse_spec
from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook, TT
from pgdcli.errors import SolverError
from pgdcli.algorithms.march import WATCH_AGREE, compile_system

EPS = np.finfo(float).eps


def _variant(name: str, edit) -> str:
    """The YAML text of problems/<name>.yaml after ``edit(data)`` (the shipped file is not touched)."""
    data = yaml.safe_load((PROBLEMS / f"{name}.yaml").read_text())
    edit(data)
    return yaml.safe_dump(data, sort_keys=False)


def _invoke(args):
    return CliRunner().invoke(cli, [str(a) for a in args], prog_name="pgd")


def _one_error_line(result) -> str:
    assert "Traceback" not in result.stderr, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.stderr
    return lines[0]


# ----------------------------------------------------------------------------------------------
# module fixtures: each problem solved once
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def coupled():
    return pgdcli.solve(load_spec(PROBLEMS / "coupled.yaml"))


@pytest.fixture(scope="module")
def coupled_train():
    """coupled.yaml through the tensor-train march (its grid fits the grid march, which it would get)."""
    with train_march():
        return pgdcli.solve(load_spec(PROBLEMS / "coupled.yaml"))


@pytest.fixture(scope="module")
def logistic():
    return pgdcli.solve(load_spec(PROBLEMS / "logistic.yaml"))


def _relaxation_march(data):
    data["solver"] = {"tolerance": 1e-9, "method": "march"}


RELAXATION_MARCH = _variant("relaxation", _relaxation_march)


@pytest.fixture(scope="module")
def relaxation_march():
    return pgdcli.solve(parse_spec(RELAXATION_MARCH, source="relaxation-march.yaml"))


def _blowup(data):
    data["coordinates"]["t"] = {"domain": [0, 1], "nodes": 12}
    for c in ("a", "b", "c"):
        data["coordinates"][c]["nodes"] = 6
    data["solver"]["tolerance"] = 1e-6


BLOWUP_TEXT = _variant("coupled", _blowup)


@pytest.fixture(scope="module")
def blowup():
    return pgdcli.solve(parse_spec(BLOWUP_TEXT, source="blowup.yaml"))


# ----------------------------------------------------------------------------------------------
# accuracy
# ----------------------------------------------------------------------------------------------
def _coupled_rhs(t, y):
    u1, u2, u3 = y.reshape(3, -1)
    return np.concatenate([1.0 - u2 * u3, 2.0 - u1 * u3, 3.0 - u1 * u2])


def _box_points(rng, n_random=200, per_face=8):
    """Random points of [0, 1]^3, all 8 corners and random points on each of the 6 faces."""
    pts = [rng.uniform(0.0, 1.0, (n_random, 3)), np.array(list(itertools.product((0.0, 1.0), repeat=3)))]
    for axis in range(3):
        for side in (0.0, 1.0):
            face = rng.uniform(0.0, 1.0, (per_face, 3))
            face[:, axis] = side
            pts.append(face)
    return np.concatenate(pts)


def test_coupled_matches_solve_ivp(coupled, record_property):
    cb = coupled.codebook
    assert coupled.converged, coupled.message
    tol = cb.report["tolerance"]
    assert tol == load_spec(PROBLEMS / "coupled.yaml").solver.tolerance
    rng = np.random.default_rng(2024)
    ics = _box_points(rng)
    assert ics.shape[0] >= 256
    nodes = cb.coordinate("t").basis().nodes  # automatic slabs: the Chebyshev nodes of every step
    assert nodes.size >= 16 and nodes[0] == 0.0 and nodes[-1] == 0.5
    times = np.unique(np.concatenate([nodes, rng.uniform(0.0, 0.5, 8)]))
    assert times.size >= 24
    # integrate from output time to output time: DOP853's dense output (t_eval) is ~6e-10 off
    state, columns, t0 = ics.T.reshape(-1), [], 0.0
    for t in times:
        if t > t0:
            sol = solve_ivp(_coupled_rhs, (t0, t), state, method="DOP853", rtol=1e-12, atol=1e-12)
            assert sol.success, sol.message
            state, t0 = sol.y[:, -1], t
        columns.append(state)
    ref = np.stack(columns, axis=1).reshape(3, ics.shape[0], times.size)  # (unknown, point, time)
    values = cb(t=times[None, :], a=ics[:, :1], b=ics[:, 1:2], c=ics[:, 2:3])  # (point, time)
    errors = {u: float(np.max(np.abs(values[u] - ref[i]))) for i, u in enumerate(("u1", "u2", "u3"))}
    record_property("coupled_max_abs_error", errors)
    print("coupled max abs error vs solve_ivp:", errors, "tolerance", tol)
    for u, e in errors.items():
        assert e <= 1e-7, (u, e)
    for u, e in errors.items():  # the solver's own tolerance bounds the error it reports
        assert e <= tol, (u, e, tol)


def test_logistic_matches_exact_solution(logistic, record_property):
    cb = logistic.codebook
    assert logistic.converged, logistic.message
    tol = cb.report["tolerance"]
    rng = np.random.default_rng(7)
    n = 500
    domains = {c.name: c.domain for c in cb.coordinates}  # the shipped spec's box
    p = {name: rng.uniform(*domains[name], n) for name in ("t", "r", "u0")}
    corners = np.array(list(itertools.product(*(domains[name] for name in ("t", "r", "u0")))))
    p = {k: np.concatenate([v, corners[:, j]]) for j, (k, v) in enumerate(p.items())}
    e = np.exp(p["r"] * p["t"])
    exact = p["u0"] * e / (1.0 - p["u0"] + p["u0"] * e)
    err = float(np.max(np.abs(cb(**p)["u"] - exact)))
    record_property("logistic_max_abs_error", err)
    print("logistic max abs error:", err, "tolerance", tol)
    assert err <= 1e-8
    assert err <= tol, (err, tol)


def test_linear_problem_forced_through_the_march(relaxation_march, record_property):
    res = relaxation_march
    cb = res.codebook
    assert res.converged, res.message
    assert cb.report["method"] == "march"
    assert all(isinstance(f, TT) for f in cb.fields.values())
    tol = cb.report["tolerance"]
    assert tol == 1e-9
    rng = np.random.default_rng(11)
    n = 1000
    p = {"t": rng.uniform(0, 3, n), "k": rng.uniform(0.5, 5, n), "a": rng.uniform(-1, 1, n),
         "u0": rng.uniform(0, 1, n)}
    t, k, a, u0 = p["t"], p["k"], p["a"], p["u0"]
    decay = np.exp(-k * t)
    exact = u0 * decay + a * (k * np.sin(2 * t) - 2 * np.cos(2 * t) + 2 * decay) / (k * k + 4.0)
    err = float(np.max(np.abs(cb(**p)["u"] - exact)))
    record_property("relaxation_march_max_abs_error", err)
    print("relaxation through the march: max abs error", err, "tolerance", tol)
    assert err <= tol, (err, tol)


# ----------------------------------------------------------------------------------------------
# the solver report
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("march", ["grid", "train"])
def test_coupled_report(march, request):
    coupled = request.getfixturevalue("coupled" if march == "grid" else "coupled_train")
    rep = coupled.codebook.report
    assert rep.get("march", "train") == march
    assert rep["converged"] is True and rep["method"] == "march"
    assert isinstance(rep["steps"], int) and rep["steps"] >= 1
    sizes = np.asarray(rep["step_sizes"])
    assert sizes.shape == (rep["steps"],)
    assert np.all(sizes > 0)
    assert float(np.sum(sizes)) == pytest.approx(0.5, rel=0, abs=1e-12)
    assert 0.0 < rep["error_estimate"] <= rep["tolerance"]
    ranks = np.asarray(rep["node_ranks"])
    nodes = coupled.codebook.coordinate("t").nodes
    assert ranks.shape == (nodes, 3, 2)  # (time nodes, unknowns, bonds of the (a, b, c) train)
    # automatic slabs: one per accepted step, each with the spec's nodes per slab
    t_info = coupled.codebook.coordinate("t")
    per_slab = load_spec(PROBLEMS / "coupled.yaml").coordinate("t").nodes
    assert len(t_info.breakpoints) == rep["steps"] + 1
    assert nodes == rep["steps"] * (per_slab - 1) + 1
    np.testing.assert_allclose(np.diff(t_info.breakpoints), sizes, rtol=0, atol=1e-12)
    if march == "train":
        np.testing.assert_array_equal(ranks[0], np.ones((3, 2)))  # u(0) = (a, b, c): rank one
    else:  # no trains at the nodes: the parameter bonds of the codebook's train bound every node's ranks
        bonds = [coupled.codebook.fields[u].ranks[1:] for u in ("u1", "u2", "u3")]
        np.testing.assert_array_equal(ranks, np.broadcast_to(bonds, ranks.shape))
    assert ranks.min() >= 1 and ranks.max() <= rep["max_rank"]
    assert f"{rep['steps']} steps" in coupled.message


@pytest.mark.parametrize("name", ["logistic", "relaxation_march"])
def test_report_error_estimate_within_tolerance(name, request):
    """A converged march must not report an error estimate above its tolerance."""
    res = request.getfixturevalue(name)
    rep = res.codebook.report
    assert res.converged
    nt = res.codebook.coordinate("t").nodes
    assert np.asarray(rep["node_ranks"]).shape[:2] == (nt, len(res.codebook.fields))
    assert float(np.sum(rep["step_sizes"])) == pytest.approx(res.codebook.coordinate("t").domain[1], abs=1e-12)
    assert rep["error_estimate"] <= rep["tolerance"], (rep["error_estimate"], rep["tolerance"], rep["steps"])


# ----------------------------------------------------------------------------------------------
# the tensor-train codebook
# ----------------------------------------------------------------------------------------------
def test_save_load_round_trip_is_bitwise(coupled, tmp_path):
    cb = coupled.codebook
    path = cb.save(tmp_path / "coupled.h5")
    back = Codebook.load(path)
    assert back.unknown_names == cb.unknown_names
    for u, fm in cb.fields.items():
        fb = back.fields[u]
        assert isinstance(fb, TT)
        assert tuple(fb.mode_order) == tuple(fm.mode_order)
        assert len(fb.cores) == len(fm.cores)
        for c0, c1 in zip(fm.cores, fb.cores):
            assert c0.shape == c1.shape and np.array_equal(c0, c1)
    rng = np.random.default_rng(3)
    p = {"t": rng.uniform(0, 0.5, 300), "a": rng.uniform(0, 1, 300), "b": rng.uniform(0, 1, 300),
         "c": rng.uniform(0, 1, 300)}
    v0, v1 = cb(**p), back(**p)
    for u in cb.unknown_names:
        assert np.array_equal(v0[u], v1[u]), u
    np.testing.assert_array_equal(back.report["node_ranks"], cb.report["node_ranks"])
    np.testing.assert_array_equal(back.report["step_sizes"], cb.report["step_sizes"])


def test_evaluation_at_nodes_equals_nodal_values(coupled):
    cb = coupled.codebook
    grids = [c.basis().nodes for c in cb.coordinates]
    d = len(grids)
    # every node of t and a; every third node of b and c, ends included (keeps the batch small)
    picks = [np.arange(g.size) if j < 2 else np.unique(np.r_[np.arange(0, g.size, 3), g.size - 1])
             for j, g in enumerate(grids)]
    coords = {c.name: g[ix].reshape([-1 if j == i else 1 for j in range(d)])
              for i, (c, g, ix) in enumerate(zip(cb.coordinates, grids, picks))}
    values = cb(**coords)
    sub = np.ix_(*picks)
    for u, fm in cb.fields.items():
        full_nodal = cb.nodal_values(u)
        assert full_nodal.shape == tuple(g.size for g in grids)
        nodal = full_nodal[sub]
        assert nodal.shape == values[u].shape
        # rounding of the contraction: gamma_n * (the contraction of |cores|), n = inner dimensions
        bound_full = np.abs(fm.cores[0][0])
        for core in fm.cores[1:]:
            bound_full = np.tensordot(bound_full, np.abs(core), axes=(-1, 0))
        bound = np.transpose(bound_full[..., 0], np.argsort(fm.mode_order))[sub]
        n = sum(fm.ranks) + len(fm.cores)
        assert np.all(np.abs(values[u] - nodal) <= 2 * n * EPS * bound), u


def test_scalar_and_broadcast_shapes(coupled):
    cb = coupled.codebook
    out = cb(t=0.25, a=0.1, b=0.2, c=0.3)
    assert list(out) == ["u1", "u2", "u3"]
    for v in out.values():
        assert isinstance(v, np.ndarray) and v.shape == ()
    t = np.array([[0.0], [0.1], [0.5]])
    a = np.array([0.0, 0.3, 0.7, 1.0])
    grid = cb(t=t, a=a, b=0.5, c=0.5)
    assert grid["u1"].shape == (3, 4)
    for i in range(3):
        for j in range(4):
            one = cb(t=float(t[i, 0]), a=float(a[j]), b=0.5, c=0.5)
            for u in cb.unknown_names:
                assert grid[u][i, j] == pytest.approx(float(one[u]), rel=1e-13, abs=1e-13)
    assert cb(t=[0.1, 0.2], a=0.5, b=0.5, c=0.5)["u2"].shape == (2,)
    assert cb(t=np.full((2, 1, 3), 0.2), a=np.full((4, 1), 0.5), b=0.5, c=0.5)["u3"].shape == (2, 4, 3)
    sel = cb.evaluate({"t": 0.2, "a": 0.5, "b": 0.5, "c": 0.5}, fields=["u3", "u1"])
    assert list(sel) == ["u3", "u1"]
    # at t = 0 the codebook gives the initial conditions
    ic = cb(t=0.0, a=0.3, b=0.6, c=0.9)
    for u, v in zip(cb.unknown_names, (0.3, 0.6, 0.9)):
        assert float(ic[u]) == pytest.approx(v, abs=1e-9)


def test_out_of_domain_query(coupled):
    with pytest.raises(pgdcli.PgdError, match="'t'.*outside the domain"):
        coupled.codebook(t=0.6, a=0.5, b=0.5, c=0.5)


def test_info_json_shows_tensor_train(coupled, tmp_path):
    path = coupled.codebook.save(tmp_path / "coupled.h5")
    result = _invoke(["info", path, "--format", "json"])
    assert result.exit_code == 0, result.stderr
    summary = json.loads(result.stdout)
    assert set(summary["unknowns"]) == {"u1", "u2", "u3"}
    for u, s in summary["unknowns"].items():
        fm = coupled.codebook.fields[u]
        assert s["representation"] == "tensor-train"
        assert s["ranks"] == list(fm.ranks)
        assert len(s["ranks"]) == 3  # (t, a, b, c): three bonds
        assert s["modes"] == max(fm.ranks)
    assert summary["converged"] is True


# ----------------------------------------------------------------------------------------------
# blow-up on t in [0, 1]
# ----------------------------------------------------------------------------------------------
def _coupled_blowup_time(ic) -> float:
    """When the coupled system's solution from ``ic`` leaves |u| <= 1e8 (scipy, independent of pgdcli):
    the pole's time to within ~1e-8."""

    def big(t, y):
        return np.max(np.abs(y)) - 1e8

    big.terminal = True
    sol = solve_ivp(lambda t, y: [1 - y[1] * y[2], 2 - y[0] * y[2], 3 - y[0] * y[1]], (0.0, 1.0), ic,
                    method="DOP853", rtol=1e-12, atol=1e-12, events=big)
    assert sol.status == 1, sol.message
    return float(sol.t_events[0][0])


BLOWUP_RE = r"blows up at t ~ ([0-9.eE+-]+) near"


def test_blowup_is_reported_with_time_and_region(blowup):
    assert blowup.converged is False
    msg = blowup.message
    m = re.search(BLOWUP_RE, msg)
    assert m, msg
    exact = _coupled_blowup_time([0.0, 1.0, 1.0])  # the corner that blows up first
    assert abs(float(m.group(1)) - exact) <= 2e-3, (msg, exact)
    for needle in ("a=0", "b=1", "c=1"):
        assert re.search(rf"\b{needle}(?![\d.])", msg), (needle, msg)
    report = blowup.codebook.report
    assert abs(report["blowup_time"] - exact) <= 2e-3
    # predicted, not reached: the march stopped before the pole, at a time the message names
    assert report["failed_time"] < exact
    assert f"stopped at t = {report['failed_time']:.6g}" in msg


def test_blowup_of_the_shipped_grid_is_predicted_early():
    """The paper's 4.2 on [0, 1] at the shipped resolution (20 nodes per IC, tolerance 1e-9): before the
    prediction it took 504 ever smaller steps (~100 s) to reach the step-size floor."""
    text = _variant("coupled", lambda d: d["coordinates"]["t"].update(domain=[0, 1]))
    result = pgdcli.solve(parse_spec(text, source="coupled01.yaml"))
    assert result.converged is False
    report = result.codebook.report
    assert report["steps"] <= 60, report
    exact = _coupled_blowup_time([0.0, 1.0, 1.0])
    assert abs(report["blowup_time"] - exact) <= 2e-3, (report["blowup_time"], exact)
    assert "a=0, b=1, c=1" in result.message


def _scalar_problem(equation: str, t_end: float, params: dict, tolerance: float, t_nodes: int = 10,
                    method: str | None = None):
    """A one-unknown problem ``u(0) = u0``: ``params`` maps a coordinate to (low, high, nodes)."""
    data = {"coordinates": {"t": {"domain": [0, t_end], "nodes": t_nodes}},
            "unknowns": {"u": {"initial": "u0"}}, "equations": [equation],
            "solver": {"tolerance": tolerance, **({"method": method} if method else {})}}
    for name, (low, high, nodes) in params.items():
        data["coordinates"][name] = {"domain": [low, high], "nodes": nodes}
    return parse_spec(yaml.safe_dump(data, sort_keys=False), source="scalar.yaml")


def test_pole_beyond_the_end_is_no_blowup():
    """u' = u^2 from u0 in [0.1, 0.5] blows up at t = 1/u0 >= 2, after the end t = 1.9: the steps shrink
    and max|u| grows 20-fold (the prediction is armed) but the pole lies outside the domain."""
    result = pgdcli.solve(_scalar_problem("der(u) = u**2", 1.9, {"u0": (0.1, 0.5, 12)}, 1e-8))
    assert_solved(result)
    assert result.codebook.report["steps"] >= 2 * 8  # long enough to arm the prediction
    # at the u0 nodes: between them 12 nodes do not resolve the pole at u0 = 1/1.9 (the resolution
    # check says so), which is not what this test is about
    t = np.linspace(0.0, 1.9, 39)[:, None]
    u0 = result.codebook.coordinates[1].basis().nodes[None, :]
    exact = u0 / (1.0 - u0 * t)
    assert exact.max() / 0.5 >= 10.0  # the growth that arms the prediction
    got = result.codebook(t=t, u0=u0)["u"]
    assert np.max(np.abs(got - exact)) <= 1e-8


class _Grid:
    shape = (3, 2)


def _watch_run(times, biggest, t_final):
    """Feed BlowupWatch accepted steps ending at ``times`` with constant states of max |u| ``biggest``."""
    from pgdcli.algorithms.blowup import BlowupWatch
    from pgdcli.tensors.tt import tt_constant

    watch = BlowupWatch(_Grid(), [tt_constant(biggest(0.0), _Grid.shape)], t_final)
    sizes = []
    for t0, t1 in zip(times, times[1:]):
        sizes.append(t1 - t0)
        found = watch(t1, sizes, [tt_constant(-biggest(t1), _Grid.shape)])
        if found is not None:
            return t1, found
    return None


def test_blowup_watch_predicts_a_pole_and_not_an_exponential():
    # a pole at t* = 0.8 approached the way the error control does: each step 5% of the distance left
    pole = 0.8
    times = [0.0]
    for _ in range(200):
        times.append(times[-1] + 0.05 * (pole - times[-1]))
    stopped, found = _watch_run(times, lambda t: 2.0 / (pole - t), t_final=1.0)
    assert stopped < pole and abs(found - pole) <= 1e-9 * pole
    # the same pole just beyond the end of the domain: no failure
    assert _watch_run([t for t in times if t < 0.78], lambda t: 2.0 / (pole - t), t_final=0.78) is None
    # exponential growth with geometrically shrinking steps (they sum to 0.5): the extrapolated zero
    # of 1/max|u| stays ahead of t, so no estimate ever agrees with an earlier one
    times = list(np.cumsum([0.0] + [0.05 * 0.9 ** k for k in range(200)]))
    assert _watch_run(times, lambda t: np.exp(20.0 * t), t_final=1.0) is None
    # a pole with a cubic term: the parabola's estimate is off, by less than the agreement asked
    def bent(t):
        return 1.0 / ((pole - t) + 40.0 * (pole - t) ** 3)

    times = [0.0]
    for _ in range(200):
        times.append(times[-1] + 0.05 * (pole - times[-1]))
    stopped, found = _watch_run(times, bent, t_final=1.0)
    assert stopped < pole and abs(found - pole) <= WATCH_AGREE * (pole - stopped)
    # growth below BLOWUP_GROWTH: the steps shrink toward a pole but the state has not grown 10-fold
    assert _watch_run(times[:30], lambda t: 2.0 / (pole - t), t_final=1.0) is None


def test_blowup_confirmation_needs_agreement_and_room_before_the_end():
    from pgdcli.algorithms.blowup import confirmed

    assert confirmed(0.9, 0.95, 0.951, 1.0)  # spread 0.001 <= 0.1 x 0.05, and 0.952 < 1
    assert not confirmed(0.9, 0.95, 0.96, 1.0)  # spread 0.01 > 0.005: not converged yet
    # the estimate lies before the end, but within twice the spread of it: the pole may be past the end
    assert not confirmed(0.9, 0.95, 0.952, 0.953)
    assert confirmed(0.9, 0.95, 0.952, 0.955)


def test_exponential_growth_is_no_blowup():
    """u' = 4 u (forced through the march) grows e^12-fold with ever smaller steps (absolute error
    control) and converges: no blow-up is predicted."""
    result = pgdcli.solve(_scalar_problem("der(u) = 4*u", 3.0, {"u0": (0.5, 1.0, 6)}, 1e-4, method="march"))
    assert result.converged, result.message
    t = np.linspace(0.0, 3.0, 31)[:, None]
    u0 = np.linspace(0.5, 1.0, 6)[None, :]
    got = result.codebook(t=t, u0=u0)["u"]
    assert np.max(np.abs(got - u0 * np.exp(4.0 * t))) <= 1e-4


def test_overflowing_trial_step_is_rejected_not_a_crash():
    """u' = -r u^3 from u0 in [1, 2], r in [50, 100]: the first trial step (h = 0.1) overflows
    (h f'(u) ~ -120); it used to end in numpy's 'SVD did not converge' traceback. Exact solution
    u0 / sqrt(1 + 2 r u0^2 t)."""
    params = {"r": (50.0, 100.0, 12), "u0": (1.0, 2.0, 8)}
    result = pgdcli.solve(_scalar_problem("der(u) = -r*u**3", 1.0, params, 1e-6, t_nodes=8))
    assert result.converged, result.message
    assert result.codebook.report["rejected_steps"] >= 1
    rng = np.random.default_rng(21)
    t, r, u0 = rng.uniform(0, 1, 2000), rng.uniform(50, 100, 2000), rng.uniform(1, 2, 2000)
    corners = np.array(list(itertools.product([0.0, 1.0], [50.0, 100.0], [1.0, 2.0]))).T
    t, r, u0 = (np.concatenate([x, c]) for x, c in zip((t, r, u0), corners))
    got = result.codebook(t=t, r=r, u0=u0)["u"]
    assert np.max(np.abs(got - u0 / np.sqrt(1.0 + 2.0 * r * u0 * u0 * t))) <= 1e-6


def test_stiff_rounding_noise_tightens_the_stage_rounding():
    """u' = r (u - u^3), r up to 200: near u = 1 the Jacobian is -2r, and the stage values' rounding
    errors reach the embedded estimate as J dY whatever the step; the march used to shrink the step
    to the floor (t = 0.78). Exact: u = u0 / sqrt(u0^2 + (1 - u0^2) exp(-2 r t)), checked at the
    parameter nodes (between them 12 nodes do not resolve r; the solve warns)."""
    params = {"r": (10.0, 200.0, 12), "u0": (0.5, 1.5, 8)}
    with train_march():  # the grid march has no stage roundings
        result = pgdcli.solve(_scalar_problem("der(u) = -r*u**3 + r*u", 1.0, params, 1e-6, t_nodes=8))
    assert_solved(result)
    cb = result.codebook
    assert cb.report["stage_tightenings"] >= 1
    t = np.random.default_rng(22).uniform(0, 1, 50)[:, None, None]
    r = cb.coordinates[1].basis().nodes[None, :, None]
    u0 = cb.coordinates[2].basis().nodes[None, None, :]
    exact = u0 / np.sqrt(u0 * u0 + (1.0 - u0 * u0) * np.exp(-2.0 * r * t))
    assert np.max(np.abs(cb(t=t, r=r, u0=u0)["u"] - exact)) <= 1e-6


def test_cli_solve_blowup_exits_1_without_codebook(tmp_path):
    spec = tmp_path / "blowup.yaml"
    spec.write_text(BLOWUP_TEXT)
    out = tmp_path / "blowup.h5"
    result = _invoke(["solve", spec, "-o", out, "-q"])
    assert result.exit_code == 1, (result.exit_code, result.stdout, result.stderr)
    assert result.stdout == ""
    line = _one_error_line(result)
    m = re.search(BLOWUP_RE, line)
    assert m and abs(float(m.group(1)) - _coupled_blowup_time([0.0, 1.0, 1.0])) <= 2e-3, line
    for needle in ("a=0", "b=1", "c=1"):
        assert re.search(rf"\b{needle}(?![\d.])", line), (needle, line)
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blowup.yaml"]


def test_cli_solve_blowup_json_is_strict_and_says_where(tmp_path):
    """A pipeline reads the failure: strict JSON (no Infinity), the user's tolerance, no placeholder ranks."""
    spec = tmp_path / "blowup.yaml"
    spec.write_text(BLOWUP_TEXT)
    result = _invoke(["solve", spec, "-o", tmp_path / "blowup.h5", "-q", "--format", "json"])
    assert result.exit_code == 1

    def reject(constant):
        raise ValueError(f"not JSON: {constant}")

    summary = json.loads(result.stdout, parse_constant=reject)
    assert summary["converged"] is False and summary["output"] is None
    assert summary["tolerance"] == yaml.safe_load(BLOWUP_TEXT)["solver"]["tolerance"]
    assert summary["residual"] is None and summary["modes"] is None and summary["ranks"] is None
    exact = _coupled_blowup_time([0.0, 1.0, 1.0])
    assert summary["failed_time"] < exact and abs(summary["blowup_time"] - exact) <= 2e-3
    assert f"t ~ {summary['blowup_time']:.4g}" in summary["message"]


# ----------------------------------------------------------------------------------------------
# method selection and compile errors
# ----------------------------------------------------------------------------------------------
PGD_ON_NONLINEAR = _variant("coupled", lambda data: data["solver"].update(method="pgd"))


def test_method_pgd_on_nonlinear_problem_is_a_solver_error(tmp_path):
    with pytest.raises(SolverError, match=r"solver\.method.*'pgd'.*linear"):
        pgdcli.solve(parse_spec(PGD_ON_NONLINEAR, source="coupled-pgd.yaml"))
    spec = tmp_path / "coupled-pgd.yaml"
    spec.write_text(PGD_ON_NONLINEAR)
    out = tmp_path / "out.h5"
    result = _invoke(["solve", spec, "-o", out, "-q"])
    assert result.exit_code == 2, (result.stdout, result.stderr)
    line = _one_error_line(result)
    assert "pgd" in line and "coupled-pgd.yaml" in line, line
    assert not out.exists()


_SMALL = spec_text(
    coordinates={'t': '{domain: [0, 0.5], nodes: 6}', 'a': '{domain: [0, 1], nodes: 4}', 'b': '{domain: [0, 1], nodes: 4}'},
    unknowns={'u1': '{initial: a}', 'u2': '{initial: b}'},
    equations=['"%s"', '"der(u2) = u1*u1"'],
)


def test_compile_rejects_two_derivatives_in_one_equation():
    problem = parse_spec(_SMALL % "der(u1) + der(u2) = u1*u2", source="two-ders.yaml")
    with pytest.raises(SolverError, match=r"two-ders\.yaml: equations\[0\].*exactly one der\(\.\.\.\).*got 2"):
        compile_system(problem)


def test_compile_rejects_a_derivative_coefficient_summed_over_coordinates():
    problem = parse_spec(_SMALL % "(a + b)*der(u1) = u1*u2", source="sum-coef.yaml")
    with pytest.raises(SolverError, match=r"sum-coef\.yaml: equations\[0\].*coefficient of der\(u1\).*a \+ b"):
        compile_system(problem)


def test_rank_cap_is_a_failure_not_a_silent_truncation():
    text = (PROBLEMS / "coupled.yaml").read_text().replace("tolerance: 1e-9", "tolerance: 1e-9\n  max_rank: 3")
    with train_march():
        result = pgdcli.solve(pgdcli.parse_spec(text, source="capped.yaml"))
    assert not result.converged
    assert "solver.max_rank=3" in result.message and "t = 0" in result.message
    # the grid march's codebook is held to the same cap: refused at the end, where its ranks are known
    result = pgdcli.solve(pgdcli.parse_spec(text, source="capped.yaml"))
    assert not result.converged
    assert "solver.max_rank=3" in result.message and "t = 0.5" in result.message


def test_nonlinear_problem_with_time_only_is_one_trajectory():
    text = spec_text(
        name=' single',
        coordinates=' {t: {domain: [0, 3], nodes: 8}}',
        unknowns=' {u: {initial: 0.2}}',
        equations=' ["der(u) = 1.5*u*(1 - u)"]',
        solver=' {tolerance: 1e-10}',
    )
    result = pgdcli.solve(parse_spec(text, source="single.yaml"))
    assert result.converged, result.message
    cb = result.codebook
    assert cb.coordinate_names == ["t"] and cb.fields["u"].mode_order == (0,)
    t = np.linspace(0.0, 3.0, 301)
    e = np.exp(1.5 * t)
    exact = 0.2 * e / (0.8 + 0.2 * e)
    assert np.max(np.abs(cb(t=t)["u"] - exact)) <= 1e-10
    assert abs(float(cb(t=1.234)["u"]) - 0.2 * np.exp(1.851) / (0.8 + 0.2 * np.exp(1.851))) <= 1e-10
