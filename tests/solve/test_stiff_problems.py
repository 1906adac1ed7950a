"""Stiff problems end to end: problems/robertson.yaml built with the automatic switch to RODAS4 and held to
its promise against an independent reference written here (scipy's Radau, analytic Jacobian, rtol 1e-10)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.sparse import block_diag

import pgdcli


def robertson_reference(k1: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Robertson's kinetics at S rates k1, each at its own time: shape (3, S). One Radau solve of the S
    systems at once (block-diagonal analytic Jacobian), rtol 1e-10, atol 1e-16, read at each sample's time."""
    S = k1.size

    def rhs(t, y):
        y1, y2, y3 = y.reshape(S, 3).T
        return np.stack([-k1 * y1 + 1e4 * y2 * y3, k1 * y1 - 1e4 * y2 * y3 - 3e7 * y2 ** 2, 3e7 * y2 ** 2],
                        axis=1).reshape(-1)

    def jac(t, y):
        y1, y2, y3 = y.reshape(S, 3).T
        blocks = [np.array([[-k, 1e4 * c, 1e4 * b], [k, -1e4 * c - 6e7 * b, -1e4 * b], [0.0, 6e7 * b, 0.0]])
                  for k, b, c in zip(k1, y2, y3)]
        return block_diag(blocks, format="csc")

    y0 = np.tile([1.0, 0.0, 0.0], S)
    sol = solve_ivp(rhs, (0.0, float(times.max())), y0, method="Radau", rtol=1e-10, atol=1e-16, jac=jac,
                    dense_output=True)
    assert sol.success
    out = np.empty((3, S))
    for i, t in enumerate(times):
        out[:, i] = sol.sol(t)[3 * i:3 * i + 3]
    return out


@pytest.mark.slow
def test_robertson_codebook_meets_its_tolerance_at_random_points_faces_and_corners():
    spec = pgdcli.load_spec("problems/robertson.yaml")
    result = pgdcli.solve(spec)
    assert result.converged and result.accurate
    report = result.codebook.report
    # DOP853 cannot resolve the first transient (~1e-4) in steps above its floor on [0, 1000]
    assert report["integrator"] == "rodas4" and report["stiff"] == 1
    assert report["integrator_reason"].startswith("solver.integrator: auto, stiff or multiscale: at t = 0 the "
                                                  "explicit DOP853 needed steps below")
    rng = np.random.default_rng(2024)
    (t0, t1), (k0, k1) = spec.coordinate("t").domain, spec.coordinate("k1").domain
    n = 300
    t = np.concatenate([t0 + (t1 - t0) * rng.random(n) ** 4,  # many early times: the transient
                        rng.uniform(t0, t1, 20), rng.uniform(t0, t1, 20),  # the faces k1 = k0, k1 = k1
                        np.full(20, t0), np.full(20, t1), [t0, t0, t1, t1]])  # the faces t = t0, t = t1; corners
    k = np.concatenate([rng.uniform(k0, k1, n), np.full(20, k0), np.full(20, k1), rng.uniform(k0, k1, 40),
                        [k0, k1, k0, k1]])
    reference = robertson_reference(k, t)
    values = result.codebook.evaluate({"t": t, "k1": k})
    tolerance, relative = spec.solver.tolerance, spec.solver.relative_tolerance
    for i, name in enumerate(("y1", "y2", "y3")):
        error = np.abs(values[name] - reference[i])
        ratio = error / (tolerance + relative * np.abs(reference[i]))
        assert ratio.max() <= 1.0, (name, error.max(), t[np.argmax(ratio)], k[np.argmax(ratio)])
    # pgd verify takes the stiff reference by itself (DOP853 would crawl at its stability limit)
    checked = pgdcli.verify(result.codebook, samples=2, times=4, max_corners=2, jobs=1)
    assert checked.settings["method"] == "Radau" and checked.settings["rtol"] == 1e-12
    assert checked.passed()


# a linear decay chain A -> B -> C whose first step is fast (a transient of 1/200 in a horizon of 5): one
# polynomial in time over the interval would need hundreds of nodes; the march steps through it
CHAIN = """
name: fast_chain
coordinates:
  t: {domain: [0, 5]}
  k2: {domain: [0.2, 2]}
unknowns:
  a: {initial: 1}
  b: {initial: 0}
  c: {initial: 0}
equations:
  - "der(a) = -200*a + 0.5*b"
  - "der(b) = 200*a - 0.5*b - k2*b"
  - "der(c) = k2*b"
solver:
  tolerance: 1e-6
  max_nodes: 65
"""


@pytest.mark.parametrize("max_nodes, why", [(65, "missed the tolerance: coordinate 't' lacks resolution"),
                                             (513, "would need more than 65 nodes in time")])
def test_a_linear_problem_with_a_fast_transient_falls_back_to_the_march(max_nodes, why):
    from scipy.linalg import expm

    spec = CHAIN.replace("max_nodes: 65", f"max_nodes: {max_nodes}")
    result = pgdcli.solve(pgdcli.parse_spec(spec, source="fast_chain.yaml"))
    assert result.accurate, result.message
    report = result.codebook.report
    assert why in report["method_fallback"] and "march ran instead" in report["method_fallback"]
    assert any("march ran instead" in w for w in result.warnings)
    rng = np.random.default_rng(5)
    worst = 0.0
    for k2 in [0.2, 2.0, *rng.uniform(0.2, 2.0, 6)]:
        times = np.concatenate([[0.0, 1e-3, 5.0], rng.uniform(0.0, 0.05, 6), rng.uniform(0.0, 5.0, 6)])
        A = np.array([[-200.0, 0.5, 0.0], [200.0, -0.5 - k2, 0.0], [0.0, k2, 0.0]])
        exact = np.stack([expm(A * t) @ [1.0, 0.0, 0.0] for t in times], axis=1)  # (3, T)
        got = result.codebook(t=times, k2=k2)
        worst = max(worst, *(float(np.max(np.abs(got[u] - exact[i]))) for i, u in enumerate("abc")))
    assert worst <= 1e-6, worst


# a filter of time constant 1e-3 driven by a sine: the explicit march is held to steps of ~1e-3 by accuracy on
# the fast mode (below its stability limit, so the watch does not call it stiff) and runs into max_steps
FILTER = """
name: filter
coordinates:
  t: {domain: [0, 2]}
  w: {domain: [0.5, 2]}
constants: {tau: 0.001}
unknowns:
  v1: {initial: 1}
  v2: {initial: 0}
equations:
  - "tau*der(v1) = sin(w*t) - v1"
  - "der(v2) = 0.5*(v1 - v2)"
solver:
  tolerance: 1e-5
  method: march
  max_steps: 1000
"""


@pytest.mark.slow
def test_an_explicit_march_held_below_its_stability_limit_switches_to_rodas4():
    """The sine holds DOP853's steps by its error estimate at h x rate 2.3, under half its limit: the watch
    switches all the same, at its third check (step 60), long before max_steps."""
    result = pgdcli.solve(pgdcli.parse_spec(FILTER, source="filter.yaml"))
    assert result.accurate, result.message
    report = result.codebook.report
    assert report["integrator"] == "rodas4" and "the explicit DOP853 was held" in report["integrator_reason"]
    assert "after 60 steps" in report["integrator_reason"]
    rng = np.random.default_rng(11)
    worst = 0.0
    for w in [0.5, 2.0, *rng.uniform(0.5, 2.0, 5)]:
        times = np.sort(np.concatenate([[0.0, 2.0], rng.uniform(0.0, 0.01, 4), rng.uniform(0.0, 2.0, 8)]))
        ref = solve_ivp(lambda t, y: [(np.sin(w * t) - y[0]) / 1e-3, 0.5 * (y[0] - y[1])], (0.0, 2.0), [1.0, 0.0],
                        method="Radau", rtol=1e-12, atol=1e-14, jac=lambda t, y: [[-1e3, 0.0], [0.5, -0.5]],
                        t_eval=times)
        got = result.codebook(t=times, w=w)
        worst = max(worst, float(np.max(np.abs(got["v1"] - ref.y[0]))), float(np.max(np.abs(got["v2"] - ref.y[1]))))
    assert worst <= 1e-5, worst


def test_an_explicit_march_at_max_steps_far_from_the_end_switches_to_rodas4():
    """max_steps before the watch's third check: the cap, far from the end, switches too."""
    text = FILTER.replace("tolerance: 1e-5", "tolerance: 1e-3").replace("max_steps: 1000", "max_steps: 58")
    result = pgdcli.solve(pgdcli.parse_spec(text, source="filter.yaml"))
    assert result.accurate, result.message
    report = result.codebook.report
    assert report["integrator"] == "rodas4" and "reached max_steps=58" in report["integrator_reason"]
    w, times = 1.3, np.linspace(0.0, 2.0, 9)
    ref = solve_ivp(lambda t, y: [(np.sin(w * t) - y[0]) / 1e-3, 0.5 * (y[0] - y[1])], (0.0, 2.0), [1.0, 0.0],
                    method="Radau", rtol=1e-12, atol=1e-14, t_eval=times)
    got = result.codebook(t=times, w=w)
    assert max(np.abs(got["v1"] - ref.y[0]).max(), np.abs(got["v2"] - ref.y[1]).max()) <= 1e-3
