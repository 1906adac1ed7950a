"""Sobol indices of shipped nonlinear codebooks against sampling estimates on the independent reference.

``scipy.stats.sobol_indices`` (Saltelli 2010 / Jansen estimators, 2^12 base samples, n (d + 2)
model runs) runs on the problem itself, integrated by ``solve_ivp`` (DOP853, rtol 1e-10): nothing
of the codebook is used. The exact indices of the codebook must fall within the sampling error:
four bootstrap standard errors of each estimate (fixed seeds: the test is deterministic).
The time of both is compared in benchmarks/sensitivity_speed.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from pgdcli.checks.reference import solve_reference
from pgdcli.problem.spec import parse_spec

pytestmark = pytest.mark.slow

TIMES = {"logistic": np.array([0.5, 1.0, 2.0]), "pendulum": np.array([0.5, 1.5, 3.0])}


@pytest.mark.parametrize("name", ["logistic", "pendulum"])
def test_exact_indices_within_the_sampling_error_of_scipy_on_solve_ivp(solved, name):
    cb = solved(name).codebook
    times = TIMES[name]
    exact = cb.sensitivity(times=times)
    problem = parse_spec(cb.spec_text, source=name)
    inputs = exact.inputs
    domains = [cb.coordinate(n).domain for n in inputs]

    def model(x):  # (d, n) -> (outputs, n): every unknown at every time, solved by solve_ivp
        result = solve_reference(problem, dict(zip(inputs, x)), times, rtol=1e-10, atol=1e-12)
        assert np.all(result.success)
        return np.concatenate([result.values[u].T for u in cb.unknown_names])

    sampled = stats.sobol_indices(func=model, n=2**12, rng=np.random.default_rng(7),
                                  dists=[stats.uniform(lo, hi - lo) for lo, hi in domains])
    boot = sampled.bootstrap(confidence_level=0.95, n_resamples=100)
    first = np.concatenate([exact.first[u] for u in cb.unknown_names])  # (outputs, d), the order of model's rows
    total = np.concatenate([exact.total[u] for u in cb.unknown_names])
    assert np.all(np.abs(first - sampled.first_order) <= 4 * boot.first_order.standard_error), \
        (first, sampled.first_order, boot.first_order.standard_error)
    assert np.all(np.abs(total - sampled.total_order) <= 4 * boot.total_order.standard_error), \
        (total, sampled.total_order, boot.total_order.standard_error)
    # and the sampling error is small enough for that to mean something
    assert np.max(boot.first_order.standard_error) < 0.05 and np.max(boot.total_order.standard_error) < 0.05
