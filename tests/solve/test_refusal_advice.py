"""Advice in a refusal works when followed: each problem is refused, solved again as the message says, and the
codebook then meets its tolerance against the exact solution at random points, on the faces and at the corners.

The oscillator x'' = -w^2 x, x(0) = 1 (x = cos(w t)) needs about 25 nodes in w at a tolerance of 1e-9; Runge's
function in p (u = exp(-t) / (1 + 400 (p - 0.3)^2)) needs elements near p = 0.3.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pgdcli
from conftest import spec_text
from pgdcli.adapt import INACCURATE
from pgdcli.progress import PhaseStarted

OSCILLATOR = spec_text(
    name=" wobble",
    coordinates={"t": "{domain: [0, 5]}", "w": "{domain: [1, 3]}"},
    unknowns={"x": "{initial: 1}", "v": "{initial: 0}"},
    equations=['"der(x) = v"', '"der(v) = -w**2*x"'],
    solver=" {tolerance: 1e-9}",
)

RUNGE = spec_text(
    name=" runge",
    coordinates={"t": "{domain: [0, 1]}", "p": "{domain: [0, 1]}"},
    unknowns={"u": '{initial: "1/(1 + 400*(p - 0.3)**2)"}'},
    equations=['"der(u) = -u"'],
    solver=" {tolerance: 1e-6}",
)


def oscillator(t, w):
    return {"x": np.cos(w * t), "v": -w * np.sin(w * t)}


def runge(t, p):
    return {"u": np.exp(-t) / (1 + 400 * (p - 0.3) ** 2)}


def solve(text: str, callback=None, **settings):
    """Solve ``text`` with ``settings`` added to (or replacing) its solver section."""
    if settings:
        solver = re.search(r"solver: \{(.*)\}", text).group(1)
        pairs = dict(kv.split(": ") for kv in solver.split(", "))
        pairs.update({k: str(v) for k, v in settings.items()})
        text = re.sub(r"solver: \{.*\}", "solver: {" + ", ".join(f"{k}: {v}" for k, v in pairs.items()) + "}", text)
    return pgdcli.solve(pgdcli.parse_spec(text, source="advice.yaml"), callback=callback)


def worst_error(cb, exact, seed: int = 0) -> float:
    """Largest error over 300 random points, the corners and points on every face of the box."""
    (a, b), (c, d) = cb.coordinate(cb.coordinate_names[0]).domain, cb.coordinate(cb.coordinate_names[1]).domain
    rng = np.random.default_rng(seed)
    s, q = rng.uniform(a, b, 300), rng.uniform(c, d, 300)
    edge = np.linspace(0, 1, 41)
    s = np.concatenate([s, [a, a, b, b], a + (b - a) * edge, a + (b - a) * edge, np.full(41, a), np.full(41, b)])
    q = np.concatenate([q, [c, d, c, d], np.full(41, c), np.full(41, d), c + (d - c) * edge, c + (d - c) * edge])
    names = cb.coordinate_names
    got, ref = cb.evaluate({names[0]: s, names[1]: q}), exact(s, q)
    return max(float(np.max(np.abs(got[u] - ref[u]))) for u in ref)


def suggested(message: str, key: str) -> int:
    match = re.search(rf"{key}: (\d+) is predicted to meet it", message)
    assert match, message
    return int(match.group(1))


@pytest.mark.parametrize("cap", [9, 17])
def test_a_coordinate_at_max_nodes_is_told_a_cap_that_meets_the_tolerance(cap):
    refused = solve(OSCILLATOR, max_nodes=cap)
    assert refused.status == INACCURATE and f"reached solver.max_nodes = {cap}" in refused.message
    new_cap = suggested(refused.message, "solver.max_nodes")
    assert new_cap > cap
    result = solve(OSCILLATOR, max_nodes=new_cap)
    assert result.accurate is True, result.message
    assert worst_error(result.codebook, oscillator) <= 1e-9


def test_elements_at_max_nodes_are_told_a_cap_that_meets_the_tolerance():
    refused = solve(RUNGE, max_nodes=65)
    assert refused.status == INACCURATE and "reached solver.max_nodes = 65" in refused.message
    assert refused.codebook.report["resolution_elements"]  # the rate is measured over elements
    result = solve(RUNGE, max_nodes=suggested(refused.message, "solver.max_nodes"))
    assert result.accurate is True, result.message
    assert worst_error(result.codebook, runge) <= 1e-6


def test_one_slow_refinement_suggests_no_cap():
    # Runge's function falls 2-fold from 9 to 17 nodes, before its scale is resolved: no rate to go by
    refused = solve(RUNGE, max_nodes=17)
    assert refused.status == INACCURATE and "too few refinements to predict" in refused.message
    assert "solver.max_nodes:" not in refused.message


def test_explicit_nodes_are_told_a_count_that_meets_the_tolerance():
    text = OSCILLATOR.replace("w: {domain: [1, 3]}", "w: {domain: [1, 3], nodes: 9}")
    refused = solve(text)
    assert refused.status == INACCURATE and "it has nodes: 9" in refused.message
    nodes = suggested(refused.message, "nodes")
    result = solve(text.replace("nodes: 9", f"nodes: {nodes}"))
    assert result.accurate is True, result.message
    assert worst_error(result.codebook, oscillator) <= 1e-9
    assert "or write 'nodes: auto'" in refused.message
    result = solve(text.replace("nodes: 9", "nodes: auto"))
    assert result.accurate is True, result.message
    assert worst_error(result.codebook, oscillator) <= 1e-9


@pytest.mark.parametrize("follow", [{"max_modes": 100}, {"method": "amen"}])
def test_an_enrichment_at_max_modes_is_told_what_takes_it(follow):
    failed = solve(OSCILLATOR, method="pgd", max_modes=3, tolerance="1e-6")
    assert not failed.converged and "(raise solver.max_modes, or solver.method: amen)" in failed.message
    result = solve(OSCILLATOR, method=follow.get("method", "pgd"), max_modes=follow.get("max_modes", 3),
                   tolerance="1e-6")
    assert result.accurate is True, result.message
    assert worst_error(result.codebook, oscillator) <= 1e-6


def test_a_march_out_of_steps_is_told_to_raise_them():
    failed = solve(OSCILLATOR, method="march", max_steps=10)
    assert not failed.converged and "raise solver.max_steps" in failed.message
    assert "stiff" not in failed.message  # 30 steps over the time domain: the cap, not stiffness
    result = solve(OSCILLATOR, method="march", max_steps=20000)
    assert result.accurate is True, result.message
    assert worst_error(result.codebook, oscillator) <= 1e-9


def test_a_state_over_the_enrichments_limit_is_told_to_march(monkeypatch):
    monkeypatch.setenv("PGD_MAX_STATE_SIZE", "40")  # 2 unknowns x 33 time nodes
    text = OSCILLATOR.replace("t: {domain: [0, 5]}", "t: {domain: [0, 5], nodes: 33}")
    with pytest.raises(pgdcli.errors.LimitError, match="solver.method: march"):
        solve(text)
    result = solve(text, method="march")
    assert result.accurate is True, result.message
    assert worst_error(result.codebook, oscillator) <= 1e-9


def solves(text: str, **settings) -> tuple[int, bool]:
    """The solves a build ran (progress events), and whether it met its tolerance."""
    events = []
    result = solve(text, events.append, **settings)
    return sum(isinstance(e, PhaseStarted) and e.what == "solve" for e in events), bool(result.accurate)


def test_a_looser_tolerance_is_never_slower_to_refuse():
    counts = [solves(RUNGE, tolerance=tol, max_nodes=65) for tol in ("1e-4", "1e-5", "1e-6", "1e-8")]
    assert not any(accurate for _, accurate in counts)
    assert [n for n, _ in counts] == sorted(n for n, _ in counts), counts


DAMPED = spec_text(
    name=" damped",
    coordinates={"t": "{domain: [0, 5]}", "k": "{domain: [1, 4]}", "c": "{domain: [0.1, 0.5]}"},
    unknowns={"x": "{initial: 1}", "v": "{initial: 0}"},
    equations=['"der(x) = v"', '"der(v) = -k*x - c*v"'],
    solver=" {tolerance: 1e-6, method: march, max_rank: 3}",
)


def test_a_march_at_max_rank_is_told_to_raise_it():
    failed = solve(DAMPED)
    assert not failed.converged and "rank reached solver.max_rank=3 (raise it)" in failed.message
    result = solve(DAMPED, max_rank=400)
    assert result.accurate is True, result.message
    cb, rng = result.codebook, np.random.default_rng(2)
    k, c = rng.uniform(1, 4, 12), rng.uniform(0.1, 0.5, 12)
    for kk, cc in zip([*k, 1, 1, 4, 4], [*c, 0.1, 0.5, 0.1, 0.5]):
        times = np.linspace(0, 5, 41)
        ref = solve_ivp(lambda s, y: [y[1], -kk * y[0] - cc * y[1]], (0, 5), [1.0, 0.0], t_eval=times,
                        rtol=1e-12, atol=1e-14)
        got = cb(t=times, k=kk, c=cc)
        assert max(np.max(np.abs(got["x"] - ref.y[0])), np.max(np.abs(got["v"] - ref.y[1]))) <= 1e-6
