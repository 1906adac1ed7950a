"""Non-separable coefficients, second-order time derivatives and x-dependent der(u, x, 2).

Every codebook here is compared with a reference written in this file (numpy right-hand sides
integrated by solve_ivp DOP853 at 1e-12, or a Chebyshev method-of-lines of its own for the PDEs),
at >= 300 random points of the domain, never with pgdcli's own reference module.
"""

import json
import pathlib

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pgdcli
from click.testing import CliRunner

from pgdcli.cli.main import cli
from pgdcli.errors import SpecError
from pgdcli.problem.expressions import parse_expression

ROOT = pathlib.Path(__file__).resolve().parents[2]
USER = ROOT / "tests" / "user_problems"
POINTS = 300


# ----------------------------------------------------------------------------------------------
# independent references
# ----------------------------------------------------------------------------------------------
def _random_points(cb, n=POINTS, seed=1):
    rng = np.random.default_rng(seed)
    return {c.name: rng.uniform(*c.domain, n) for c in cb.coordinates}


def _ode_reference(rhs, y0, t, t_end):
    """Every sample integrated in one vectorized DOP853 call at 1e-12; values at each sample's own time.

    rhs(t, Y) with Y of shape (q, S) -> (q, S); y0 (q, S); t (S,) the times asked.
    """
    q, S = y0.shape
    sol = solve_ivp(lambda s, y: rhs(s, y.reshape(q, S)).ravel(), (0.0, t_end), y0.ravel(), method="DOP853",
                    rtol=1e-12, atol=1e-12, dense_output=True)
    assert sol.success
    return np.stack([sol.sol(ti).reshape(q, S)[:, i] for i, ti in enumerate(t)], axis=1)  # (q, S)


def _cheb(n, domain):
    """Chebyshev-Lobatto nodes (increasing) and differentiation matrix on a domain."""
    k = np.arange(n)
    x = -np.cos(np.pi * k / (n - 1))
    c = np.where((k == 0) | (k == n - 1), 2.0, 1.0) * (-1.0) ** k
    dx = x[:, None] - x[None, :]
    D = np.outer(c, 1 / c) / (dx + np.eye(n))
    D -= np.diag(D.sum(axis=1))
    low, high = domain
    return low + (x + 1) * (high - low) / 2, D * 2 / (high - low)


def _mol_reference(rhs_interior, x, u0, t):
    """Method of lines: BDF at rtol 1e-10, atol 1e-12; values (len(t), n) at the times t (sorted)."""
    sol = solve_ivp(rhs_interior, (0.0, float(t[-1])), u0, method="BDF", rtol=1e-10, atol=1e-12, t_eval=t,
                    jac_sparsity=None)
    assert sol.success
    return sol.y.T


def _interpolate(nodes, values, x):
    """Polynomial interpolation through Chebyshev nodes (barycentric weights of the Lobatto points)."""
    n = nodes.size
    w = (-1.0) ** np.arange(n)
    w[0] *= 0.5
    w[-1] *= 0.5
    d = x[:, None] - nodes[None, :]
    exact = np.isclose(d, 0.0, atol=1e-15)
    d[exact] = 1.0
    k = w / d
    out = (k @ values) / k.sum(axis=1)
    rows, cols = np.nonzero(exact)
    out[rows] = values[cols]
    return out


# ----------------------------------------------------------------------------------------------
# parsing
# ----------------------------------------------------------------------------------------------
def _parse(text):
    return parse_expression(text, coordinates=("t", "w", "a", "b", "k", "x"), constants={"F": 2.0},
                            unknowns=("u", "v"), time="t", where="test")


@pytest.mark.parametrize("text, exact", [
    ("sin(w*t)", lambda v: np.sin(v["w"] * v["t"])),
    ("F*k*sin(w*t) - cos(w*t)/2", lambda v: 2 * v["k"] * np.sin(v["w"] * v["t"]) - np.cos(v["w"] * v["t"]) / 2),
    ("exp(-k*x*t)", lambda v: np.exp(-v["k"] * v["x"] * v["t"])),
    ("1/(1 + a*b)", lambda v: 1 / (1 + v["a"] * v["b"])),
    ("exp(-k - a*t)", lambda v: np.exp(-v["k"] - v["a"] * v["t"])),
    ("(1 + a*b)**0.5 + a**t", lambda v: np.sqrt(1 + v["a"] * v["b"]) + v["a"] ** v["t"]),
    ("2**(a*t) * (sin(w*t) + 1)**2", lambda v: 2 ** (v["a"] * v["t"]) * (np.sin(v["w"] * v["t"]) + 1) ** 2),
    ("abs(a - b)*k", lambda v: np.abs(v["a"] - v["b"]) * v["k"]),
])
def test_non_separable_coefficients_are_kept_and_evaluate_exactly(text, exact):
    poly = _parse(text)
    sep = poly.coefficient(())
    assert sep.joints, "expected a non-separable part"
    rng = np.random.default_rng(0)
    values = {c: rng.uniform(0.1, 2, 50) for c in ("t", "w", "a", "b", "k", "x")}
    np.testing.assert_allclose(sep.evaluate(**values), exact(values), rtol=1e-13, atol=1e-13)
    # the rendered text parses back to the same function
    again = _parse(str(sep)).coefficient(())
    np.testing.assert_allclose(again.evaluate(**values), exact(values), rtol=1e-12, atol=1e-13)


def test_separable_factors_stay_outside_the_joint_function():
    sep = _parse("F*k*sin(w*t)*u").coefficient((pgdcli.problem.expressions.Atom("u"),))
    (joint,) = sep.joints
    assert joint.tree_coordinates == {"t", "w"}
    assert joint.term.coordinates == {"k"} and joint.term.coef == 2.0


# ----------------------------------------------------------------------------------------------
# second-order time derivatives: the spec
# ----------------------------------------------------------------------------------------------
SECOND = """
coordinates:
  t: {{domain: [0, 1]}}
  k: {{domain: [1, 2]}}
unknowns:
  x: {{initial: {initial}}}
equations:
  - "{equation}"
"""


def _second(initial="{value: 1, rate: k}", equation="der(x, t, 2) = -k*x - 0.5*der(x)", **kw):
    return pgdcli.parse_spec(SECOND.format(initial=initial, equation=equation), **kw)


def test_second_order_equation_becomes_a_first_order_system_with_a_rate():
    problem = _second()
    assert problem.unknown_names == ("x", "x_rate")
    assert problem.unknowns[1].rate_of == "x" and problem.unknowns[1].initial_text == "k"
    texts = [str(eq.polynomial) for eq in problem.equations]
    assert texts == ["k*x + 0.5*x_rate + der(x_rate, t)", "der(x, t) - x_rate"]


def test_second_order_on_either_side_and_with_the_rate_named():
    problem = _second(equation="-k*x - 0.5*x_rate = der(x, t, 2)")
    assert [str(eq.polynomial) for eq in problem.equations][0] == "-k*x - 0.5*x_rate - der(x_rate, t)"


@pytest.mark.parametrize("initial, equation, message", [
    ("1", "der(x, t, 2) = -x", "equations[0]: der(x, t, 2) needs the initial rate of 'x': write its initial "
                               "condition as {value: <x0>, rate: <v0>}"),
    ("{value: 1, rate: 0}", "der(x) = -x", "unknowns.x.initial: an initial rate is given but der(x, t, 2) appears "
                                           "in no equation"),
    ("{value: 1}", "der(x, t, 2) = -x", "unknowns.x.initial: missing required key 'rate'"),
    ("{value: 1, rate: 0, speed: 2}", "der(x, t, 2) = -x", "unknowns.x.initial: unknown key 'speed' (allowed: value, "
                                                           "rate)"),
    ("{value: 1, rate: t}", "der(x, t, 2) = -x", "must not depend on the time coordinate 't'"),
    ("{value: 1, rate: 0}", "der(x, t, 2) = -x + der(x_rate)", "'der(x_rate)' in 'der(x, t, 2) = -x + der(x_rate)': "
                                                               "write the derivative of the rate of 'x' as der(x, t, 2)"),
    ("{value: 1, rate: 0}", "der(x, t, 2)*x = -x", "multiplies a derivative by an unknown"),
])
def test_second_order_errors_name_the_key(initial, equation, message):
    with pytest.raises(SpecError) as info:
        _second(initial=initial, equation=equation)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_a_rate_name_that_is_taken_is_an_error():
    text = SECOND.format(initial="{value: 1, rate: 0}", equation="der(x, t, 2) = -x").replace(
        "k: {domain: [1, 2]}", "x_rate: {domain: [1, 2]}")
    with pytest.raises(SpecError, match="the rate of 'x' is the unknown 'x_rate', a name already used by "
                                        "coordinates.x_rate; rename that"):
        pgdcli.parse_spec(text)


# ----------------------------------------------------------------------------------------------
# shipped forced.yaml and fresh user problems against independent references
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def forced(tmp_path_factory):
    result = pgdcli.solve(ROOT / "problems" / "forced.yaml")
    assert result.converged, result.message
    path = tmp_path_factory.mktemp("forced") / "forced.h5"
    result.codebook.save(path)
    return result, path


def test_forced_against_solve_ivp_at_300_random_points(forced):
    result, _ = forced
    cb = result.codebook
    assert cb.unknown_names == ["x", "x_rate"]
    p = _random_points(cb)

    def rhs(t, y):  # x'' = -x - c x' + sin(w t)
        return np.stack([y[1], -y[0] - p["c"] * y[1] + np.sin(p["w"] * t)])

    ref = _ode_reference(rhs, np.zeros((2, POINTS)), p["t"], 10.0)
    got = cb(**p)
    assert np.max(np.abs(got["x"] - ref[0])) <= 1e-6
    assert np.max(np.abs(got["x_rate"] - ref[1])) <= 1e-6
    assert "sin(t*w) [t, w]" in cb.report["separated_coefficients"]


def _pgd(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], prog_name="pgd")


def test_forced_cli_info_query_verify(forced):
    _, path = forced
    result = _pgd("info", path, "--format", "json")
    assert result.exit_code == 0
    info = json.loads(result.stdout)
    assert info["rates"] == {"x_rate": "x"}
    assert any(line.startswith("sin(t*w) [t, w]:") and " terms " in line for line in info["separated_coefficients"])
    out = _pgd("info", path).stdout
    assert "rates: x_rate = der(x)" in out and "separated coefficient: sin(t*w) [t, w]" in out
    result = _pgd("query", path, "--t", "3", "--w", "1", "--c", "0.2", "--field", "x_rate", "--format", "csv")
    assert result.exit_code == 0
    row = result.stdout.splitlines()
    assert row[0] == "t,w,c,x_rate"
    ref = solve_ivp(lambda t, y: [y[1], -y[0] - 0.2 * y[1] + np.sin(t)], (0, 3), [0, 0], method="DOP853",
                    rtol=1e-12, atol=1e-12)
    assert abs(float(row[1].split(",")[-1]) - ref.y[1, -1]) <= 1e-6
    result = _pgd("verify", path, "--samples", "16", "--max-error", "1e-6", "--format", "json")
    assert result.exit_code == 0, result.stderr


def _solved(name):
    result = pgdcli.solve(USER / f"{name}.yaml")
    assert result.converged, result.message
    return result.codebook


def test_decaying_forcing_against_solve_ivp():
    cb = _solved("decaying_forcing")
    p = _random_points(cb, seed=2)

    def rhs(t, y):
        return np.stack([y[1], -2 * y[0] - 0.3 * y[1] + np.exp(-p["a"] * t) * np.sin(p["w"] * t)])

    ref = _ode_reference(rhs, np.zeros((2, POINTS)), p["t"], 8.0)
    got = cb(**p)
    assert np.max(np.abs(got["x"] - ref[0])) <= 1e-6 and np.max(np.abs(got["x_rate"] - ref[1])) <= 1e-6
    assert cb.info()["method"] == "pgd" and "exp(-a*t)*sin(t*w) [a, t, w]" in cb.report["separated_coefficients"]


def test_forced_aux_written_naturally_against_solve_ivp():
    cb = _solved("forced_natural")
    p = _random_points(cb, seed=9)

    def rhs(t, y):
        return np.stack([y[1], -y[0] - 0.2 * y[1] + np.sin(p["w"] * t)])

    ref = _ode_reference(rhs, np.zeros((2, POINTS)), p["t"], 10.0)
    got = cb(**p)
    assert np.max(np.abs(got["x"] - ref[0])) <= 1e-6 and np.max(np.abs(got["x_rate"] - ref[1])) <= 1e-6


def test_oscillator_with_a_rate_initial_condition_against_the_exact_solution():
    cb = _solved("oscillator_rate")
    p = _random_points(cb, seed=3)
    got = cb(**p)
    w0, t = p["w0"], p["t"]
    x = p["x0"] * np.cos(w0 * t) + p["v0"] / w0 * np.sin(w0 * t)
    v = -p["x0"] * w0 * np.sin(w0 * t) + p["v0"] * np.cos(w0 * t)
    assert np.max(np.abs(got["x"] - x)) <= 1e-6 and np.max(np.abs(got["x_rate"] - v)) <= 1e-6


@pytest.mark.slow
def test_forced_duffing_marches_and_matches_solve_ivp():
    cb = _solved("duffing_forced")
    assert cb.report["method"] == "march"
    p = _random_points(cb, seed=4)

    def rhs(t, y):
        return np.stack([y[1], -y[0] - y[0] ** 3 - 0.2 * y[1] + 0.5 * np.cos(p["w"] * t)])

    ref = _ode_reference(rhs, np.stack([p["x0"], np.zeros(POINTS)]), p["t"], 5.0)
    got = cb(**p)
    assert np.max(np.abs(got["x"] - ref[0])) <= 1e-6 and np.max(np.abs(got["x_rate"] - ref[1])) <= 1e-6


def test_non_separable_time_constant_against_the_exact_solution():
    cb = _solved("saturating_relaxation")
    p = _random_points(cb, seed=5)
    tau = 1 + p["a"] * p["b"]
    exact = tau * (1 - np.exp(-p["t"] / tau))
    assert np.max(np.abs(cb(**p)["u"] - exact)) <= 1e-7
    assert "1/(1 + a*b) [a, b]" in cb.report["separated_coefficients"]


def test_non_separable_coefficient_in_the_march_against_solve_ivp():
    text = (USER / "saturating_relaxation.yaml").read_text().replace("1 - u/(1 + a*b)", "1 - u**2/(1 + a*b)")
    result = pgdcli.solve(pgdcli.parse_spec(text, source="quadratic.yaml"))
    assert result.converged and result.codebook.report["method"] == "march"
    cb = result.codebook
    p = _random_points(cb, seed=6)
    ref = _ode_reference(lambda t, y: 1 - y ** 2 / (1 + p["a"] * p["b"]), np.zeros((1, POINTS)), p["t"], 4.0)
    assert np.max(np.abs(cb(**p)["u"] - ref[0])) <= 1e-7


def _pde_check(cb, rhs_of, initial, n=40, samples=30, per=10, seed=7):
    """Own method of lines at `samples` parameter points x `per` random (t, x) each (300 points)."""
    rng = np.random.default_rng(seed)
    coords = {c.name: c for c in cb.coordinates}
    (pname,) = [c for c in coords if c not in ("t", "x")]
    x, D = _cheb(n, coords["x"].domain)
    worst = 0.0
    for value in rng.uniform(*coords[pname].domain, samples):
        t = np.sort(rng.uniform(*coords["t"].domain, per))
        xs = rng.uniform(*coords["x"].domain, per)
        rhs, full = rhs_of(value, x, D)
        u = _mol_reference(rhs, x, initial(x)[1:-1] if full is None else initial(x), t)
        values = np.array([_interpolate(x, full(ui) if full is not None else np.r_[0.0, ui, 0.0], xs[i:i + 1])[0]
                           for i, ui in enumerate(u)])
        got = cb(**{"t": t, "x": xs, pname: np.full(per, value)})["u"]
        worst = max(worst, float(np.max(np.abs(got - values))))
    return worst


@pytest.mark.slow
def test_heat_with_a_non_separable_source_against_a_method_of_lines():
    cb = _solved("heat_decaying_source")
    (line,) = cb.info()["separated_coefficients"]
    assert line.startswith("exp(-k*t*x)*sin(") and sorted(line.split("[")[1].split("]")[0].split(", ")) == ["k", "t", "x"]

    def rhs_of(k, x, D):
        D2 = (D @ D)[1:-1, 1:-1]  # u = 0 at both ends
        return (lambda t, u: 0.5 * D2 @ u + np.exp(-k * x[1:-1] * t) * np.sin(np.pi * x[1:-1])), None

    assert _pde_check(cb, rhs_of, lambda x: np.zeros_like(x)) <= 1e-6


@pytest.mark.slow
def test_conduction_in_divergence_form_with_a_neumann_end_against_a_method_of_lines():
    cb = _solved("conduction_variable")

    def rhs_of(a, x, D):
        # unknowns: the values at all nodes but x = 0 (u = 0 there); the last row is the condition u_x(1) = 0.5
        kx = 1 + a * x ** 2
        D2 = D @ D

        def full(u):
            return np.r_[0.0, u, _end(u)]

        def _end(u):  # D[-1] @ [0, u, e] = 0.5 -> e
            return (0.5 - D[-1, 1:-1] @ u) / D[-1, -1]

        def rhs(t, u):
            v = full(u)
            return (kx * (D2 @ v) + 2 * a * x * (D @ v))[1:-1]

        return rhs, lambda w: full(w)

    def initial(x):
        return (np.sin(np.pi * x / 2) + 0.5 * x)[1:-1]

    assert _pde_check(cb, rhs_of, initial) <= 1e-6


@pytest.mark.slow
def test_x_dependent_conduction_on_linear_elements_against_a_method_of_lines():
    text = (USER / "conduction_variable.yaml").read_text().replace(
        "x: {domain: [0, 1]}", "x: {domain: [0, 1], discretization: linear}").replace("tolerance: 1e-6", "tolerance: 1e-4")
    result = pgdcli.solve(pgdcli.parse_spec(text, source="linear.yaml"))
    assert result.converged, result.message
    assert result.codebook.coordinate("x").discretization == "linear"

    def rhs_of(a, x, D):
        kx, D2 = 1 + a * x ** 2, D @ D

        def full(u):
            return np.r_[0.0, u, (0.5 - D[-1, 1:-1] @ u) / D[-1, -1]]

        return (lambda t, u: (kx * (D2 @ full(u)) + 2 * a * x * (D @ full(u)))[1:-1]), full

    assert _pde_check(result.codebook, rhs_of, lambda x: (np.sin(np.pi * x / 2) + 0.5 * x)[1:-1]) <= 1e-4


@pytest.mark.slow
def test_wave_equation_second_order_in_time_against_the_exact_solution():
    cb = _solved("string_wave")
    p = _random_points(cb, seed=10)
    x, c, t = p["x"], p["c"], p["t"]
    got = cb(**p)
    assert np.max(np.abs(got["u"] - np.sin(np.pi * x) * np.cos(np.pi * c * t))) <= 1e-6
    assert np.max(np.abs(got["u_rate"] + np.pi * c * np.sin(np.pi * x) * np.sin(np.pi * c * t))) <= 1e-6


def test_x_dependent_coefficient_of_der_u_x_2_is_accepted_by_the_linear_solver():
    problem = pgdcli.load_spec(USER / "conduction_variable.yaml")
    from pgdcli.discretization.linear import discretize

    disc = discretize(problem)
    assert disc.operator.n_terms >= 2


# ----------------------------------------------------------------------------------------------
# refusals
# ----------------------------------------------------------------------------------------------
def test_a_coefficient_beyond_the_rank_cap_is_one_line_naming_it(tmp_path):
    spec = tmp_path / "cap.yaml"
    spec.write_text("coordinates:\n  t: {domain: [0, 10], nodes: 60}\n  w: {domain: [1, 20], nodes: 60}\n"
                    "unknowns:\n  x: {initial: 0}\nequations:\n  - der(x) = -x + sin(w*t)\nsolver:\n  max_rank: 8\n")
    result = _pgd("solve", spec, "-o", tmp_path / "cap.h5", "-q")
    assert result.exit_code == 2 and result.stdout == ""
    (err,) = result.stderr.strip().splitlines()
    assert err.startswith("Error: ") and "the coefficient 'sin(t*w)' does not separate on the nodes of t, w: rank 8 " \
                                             "reached" in err
    assert not (tmp_path / "cap.h5").exists()


@pytest.mark.slow
def test_a_non_separable_coefficient_of_an_unknown_in_a_pde_against_a_method_of_lines():
    text = (USER / "heat_decaying_source.yaml").read_text().replace(
        "D*der(u, x, 2) + exp(-k*x*t)*sin(pi*x)", "D*der(u, x, 2) - exp(-k*x*t)*u + sin(pi*x)")
    result = pgdcli.solve(pgdcli.parse_spec(text, source="absorption.yaml"))
    assert result.converged and result.accurate, result.message
    cb = result.codebook

    def rhs_of(k, x, D):
        D2 = (D @ D)[1:-1, 1:-1]
        xi = x[1:-1]
        return (lambda t, u: 0.5 * D2 @ u - np.exp(-k * xi * t) * u + np.sin(np.pi * xi)), None

    assert _pde_check(cb, rhs_of, lambda x: np.zeros_like(x)) <= 1e-6


def test_solve_json_and_table_say_how_many_terms(tmp_path):
    result = _pgd("solve", USER / "saturating_relaxation.yaml", "-o", tmp_path / "s.h5", "--format", "json", "-q")
    assert result.exit_code == 0, result.stderr
    (line,) = json.loads(result.stdout)["separated_coefficients"]
    assert line.startswith("1/(1 + a*b) [a, b]: ") and " terms (svd" in line
    table = _pgd("solve", USER / "saturating_relaxation.yaml", "-o", tmp_path / "s.h5").stderr
    assert "separated" in table and "1/(1 + a*b) [a, b]" in table


def test_a_non_separable_boundary_value_is_refused_naming_the_key():
    text = (USER / "heat_decaying_source.yaml").read_text().replace("x: {low: 0, high: 0}",
                                                                      "x: {low: 0, high: {gradient: 1/(1 + k*t)}}")
    with pytest.raises(SpecError, match=r"unknowns.u.boundary.x.high: a boundary value must be a sum of products of "
                                        r"one-coordinate functions; '1/\(1 \+ k\*t\)'"):
        pgdcli.parse_spec(text, source="b.yaml")


def test_a_non_separable_initial_value_is_separated_and_checked():
    text = (USER / "saturating_relaxation.yaml").read_text().replace("u: {initial: 0}", "u: {initial: 1/(1 + a*b)}")
    result = pgdcli.solve(pgdcli.parse_spec(text, source="i.yaml"))
    assert result.converged
    cb = result.codebook
    p = _random_points(cb, seed=8)
    tau = 1 + p["a"] * p["b"]
    exact = tau + (1 / tau - tau) * np.exp(-p["t"] / tau)
    assert np.max(np.abs(cb(**p)["u"] - exact)) <= 1e-7
