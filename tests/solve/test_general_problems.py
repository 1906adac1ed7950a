"""Functions of the unknowns in the march: shipped and user-written problems against solve_ivp.

Each spec is written the natural way (``sin(th)``, ``v*sqrt(vx**2 + vy**2)``, ``exp(-a*x)``,
``s/(km + s)``) without node counts; its codebook must be within the spec's tolerance at 300
random points of the domain against solve_ivp (DOP853, rtol = atol = 1e-12) of right-hand sides
written here in numpy, sharing nothing with pgdcli.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pgdcli
from conftest import train_march

ROOT = Path(__file__).resolve().parents[2]
GRAV = 9.81

PROBLEMS = {
    "problems/pendulum.yaml": (lambda t, y, p: [y[1], -GRAV / p["L"] * np.sin(y[0])],
                               lambda p: [p["th0"], 0.0]),
    "problems/drag.yaml": (lambda t, y, p: [y[2], y[3], -p["k"] * y[2] * np.hypot(y[2], y[3]),
                                            -GRAV - p["k"] * y[3] * np.hypot(y[2], y[3])],
                           lambda p: [0.0, 0.0, 20 * np.cos(p["a"]), 20 * np.sin(p["a"])]),
    "tests/user_problems/damped_pendulum.yaml": (lambda t, y, p: [y[1], -4 * np.sin(y[0]) - p["c"] * y[1]],
                                                 lambda p: [p["th0"], 0.0]),
    "tests/user_problems/driven_pendulum.yaml": (lambda t, y, p: [y[1], -4 * np.sin(y[0] - 0.3 * np.sin(p["W"] * t))
                                                                  - 0.2 * y[1]], lambda p: [p["th0"], 0.0]),
    "tests/user_problems/pendulum_natural.yaml": (lambda t, y, p: [y[1], -GRAV / p["L"] * np.sin(y[0])
                                                                   + 0.3 * np.sin(p["L"] * t) * np.cos(y[0])],
                                                  lambda p: [p["th0"], 0.0]),
    "tests/user_problems/morse.yaml": (lambda t, y, p: [y[1], -4 * p["a"] * (np.exp(-p["a"] * y[0])
                                                                             - np.exp(-2 * p["a"] * y[0]))],
                                       lambda p: [p["x0"], 0.0]),
    "tests/user_problems/drag3.yaml": (lambda t, y, p: [-p["k"] * y[0] * np.hypot(y[0], y[1]),
                                                        -GRAV - p["k"] * y[1] * np.hypot(y[0], y[1])],
                                       lambda p: [p["v0"] * np.cos(p["a"]), p["v0"] * np.sin(p["a"])]),
    "tests/user_problems/michaelis.yaml": (lambda t, y, p: [-p["vmax"] * y[0] / (p["km"] + y[0]),
                                                            p["vmax"] * y[0] / (p["km"] + y[0])],
                                           lambda p: [1.0, 0.0]),
}


def worst_error(name: str, cb, samples: int = 300, seed: int = 14) -> float:
    rhs, initial = PROBLEMS[name]
    rng = np.random.default_rng(seed)
    t0, t1 = cb.coordinate("t").domain
    params = [c for c in cb.coordinates if c.role != "time"]
    worst = 0.0
    for _ in range(samples):
        p = {c.name: rng.uniform(*c.domain) for c in params}
        t = rng.uniform(t0, t1)
        sol = solve_ivp(lambda s, y: rhs(s, y, p), (t0, t1), initial(p), method="DOP853", rtol=1e-12, atol=1e-12,
                        t_eval=[t])
        got = cb(t=t, **p)
        worst = max(worst, max(abs(float(got[u]) - sol.y[i, 0]) for i, u in enumerate(cb.unknown_names)))
    return worst


@pytest.mark.slow
@pytest.mark.parametrize("march", ["grid", "train"])
@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_within_tolerance_at_random_points(name, march):
    problem = pgdcli.load_spec(ROOT / name)
    assert all(c.auto for c in problem.coordinates)  # written without node counts
    with contextlib.nullcontext() if march == "grid" else train_march():
        result = pgdcli.solve(problem)
    assert result.accurate, result.message
    assert result.codebook.report["method"] == "march"
    if march == "grid":  # these grids are small: the whole array marches, the general terms evaluated on it
        assert result.codebook.report["march"] == "grid"
    else:
        assert result.codebook.report["crosses"] > 0
    assert worst_error(name, result.codebook) <= problem.solver.tolerance


def test_verify_checks_a_codebook_with_functions_of_the_unknowns(tmp_path):
    problem = pgdcli.load_spec(ROOT / "problems" / "drag.yaml")
    result = pgdcli.solve(problem)
    path = tmp_path / "drag.h5"
    result.codebook.save(path)
    report = pgdcli.verify(path, samples=32, seed=5, jobs=1)
    assert report.passed(max_error=1e-6)
    # and it is not vacuous: the same verify fails a codebook of the drag-free problem
    free = pgdcli.parse_spec((ROOT / "problems" / "drag.yaml").read_text().replace("k*vx*sqrt", "0*k*vx*sqrt")
                             .replace("- k*vy*sqrt", "- 0*k*vy*sqrt"), source="free.yaml")
    wrong = pgdcli.solve(free).codebook
    wrong.spec_text = (ROOT / "problems" / "drag.yaml").read_text()  # the drag-free codebook, labelled drag
    wrong_path = tmp_path / "wrong.h5"
    wrong.save(wrong_path)
    assert not pgdcli.verify(wrong_path, samples=32, seed=5, jobs=1).passed(max_error=1e-6)


@pytest.mark.slow
def test_march_with_the_cross_forced_meets_the_tolerance(monkeypatch):
    # up to ~4 parameters the march evaluates general terms on the whole grid; force the TT-cross
    from pgdcli.algorithms import general_rhs

    monkeypatch.setattr(general_rhs, "DENSE_LIMIT", 0)
    monkeypatch.setattr(general_rhs, "SWEEPS_PER_CROSS", 0)
    messages = []
    cross = general_rhs.tt_cross

    def recorded(*args, **kwargs):
        result = cross(*args, **kwargs)
        messages.append(result.message)
        return result

    monkeypatch.setattr(general_rhs, "tt_cross", recorded)
    name = "tests/user_problems/drag3.yaml"
    problem = pgdcli.load_spec(ROOT / name)
    with train_march():
        result = pgdcli.solve(problem)
    assert result.accurate, result.message
    assert messages and all(m.startswith("converged in") for m in messages)  # DMRG crosses, no whole grids
    assert result.codebook.report["crosses_not_converged"] == 0
    assert worst_error(name, result.codebook) <= problem.solver.tolerance
