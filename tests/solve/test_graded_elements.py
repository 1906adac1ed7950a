"""Parameters whose solution depends on the log-distance to an end of the box get elements graded toward that
end, and the codebook meets its tolerance against an independent reference at random points, on every face
and at the corners."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pgdcli

#: Van der Pol from rest near the unstable origin: the time to reach the limit cycle grows like log(1/x0).
VAN_DER_POL = """name: vdp_start
coordinates:
  t: {domain: [0, 20]}
  x0: {domain: [0.001, 2]}
unknowns:
  x: {initial: x0}
  v: {initial: 0}
equations:
  - "der(x) = v"
  - "der(v) = (1 - x**2)*v - x"
solver:
  tolerance: 1e-6
"""

#: Decay at rates from 0 to 1 over a long time: exp(-k t) varies in k on a scale 1/t, all of it near k = 0.
SLOW_DECAY = """name: slow_decay
coordinates:
  t: {domain: [0, 200]}
  k: {domain: [0, 1]}
unknowns:
  u: {initial: 1}
equations:
  - "der(u) = -k*u"
solver:
  tolerance: 1e-6
"""


def sample(cb, n: int = 300, per_face: int = 20, seed: int = 3) -> dict:
    """Random points, points on every face (one coordinate at an end) and the corners of the box."""
    rng = np.random.default_rng(seed)
    names = cb.coordinate_names
    rows = [rng.uniform(*cb.coordinate(m).domain, n) for m in names]
    for j, face in itertools.product(range(len(names)), (0, 1)):
        for i, m in enumerate(names):
            rows[i] = np.concatenate([rows[i], np.full(per_face, cb.coordinate(m).domain[face]) if i == j
                                      else rng.uniform(*cb.coordinate(m).domain, per_face)])
    corners = np.array(list(itertools.product(*(cb.coordinate(m).domain for m in names)))).T
    return {m: np.concatenate([rows[i], corners[i]]) for i, m in enumerate(names)}


def graded_toward_low_end(cb, name: str) -> bool:
    widths = np.diff(cb.coordinate(name).breakpoints)
    return widths.size >= 3 and widths[0] < 0.05 * widths.max() and np.all(np.diff(widths[:3]) > 0)


@pytest.mark.slow
def test_van_der_pol_from_near_its_unstable_point_is_graded_and_within_its_tolerance():
    result = pgdcli.solve(pgdcli.parse_spec(VAN_DER_POL, source="vdp_start.yaml"))
    assert result.accurate is True, result.message
    cb = result.codebook
    assert graded_toward_low_end(cb, "x0"), cb.coordinate("x0").breakpoints
    p = sample(cb)
    # one vectorized reference over all the points' x0, read at each point's time from its dense output
    n = p["x0"].size

    def rhs(_, y):
        x, v = y[:n], y[n:]
        return np.concatenate([v, (1 - x**2) * v - x])

    ref = solve_ivp(rhs, (0, 20), np.concatenate([p["x0"], np.zeros(n)]), method="DOP853", rtol=1e-12,
                    atol=1e-14, dense_output=True)
    exact = np.array([ref.sol(t)[[i, n + i]] for i, t in enumerate(p["t"])])
    got = cb.evaluate(p)
    assert max(np.max(np.abs(got["x"] - exact[:, 0])), np.max(np.abs(got["v"] - exact[:, 1]))) <= 1e-6


def test_a_slow_decay_near_a_zero_rate_is_graded_and_within_its_tolerance():
    result = pgdcli.solve(pgdcli.parse_spec(SLOW_DECAY, source="slow_decay.yaml"))
    assert result.accurate is True, result.message
    cb = result.codebook
    assert graded_toward_low_end(cb, "k"), cb.coordinate("k").breakpoints
    p = sample(cb)
    assert np.max(np.abs(cb.evaluate(p)["u"] - np.exp(-p["k"] * p["t"]))) <= 1e-6
