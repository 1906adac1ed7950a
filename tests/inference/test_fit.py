"""pgdcli.fit and ``pgd fit``: parameter identification from synthetic data made by the reference."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import PROBLEMS

import pgdcli
from pgdcli.cli.main import cli
from pgdcli.inference.fitting import FitError, read_data
from pgdcli.checks.reference import solve_reference
from pgdcli.problem.spec import load_spec


def synthetic(name, truth, times, observed, noise, seed=0, extra=None):
    """Data made by the independent reference (solve_ivp) at ``truth``, plus Gaussian noise."""
    problem = load_spec(PROBLEMS / f"{name}.yaml")
    params = {k: np.array([v], dtype=float) for k, v in {**truth, **(extra or {})}.items()}
    ref = solve_reference(problem, params, times)
    rng = np.random.default_rng(seed)
    data = {"t": np.asarray(times, dtype=float)}
    for u in observed:
        data[u] = ref.values[u][0] + rng.normal(0.0, noise, len(times))
    return data


def assert_recovered(result, truth, max_stderr):
    """Every estimate within 3 of its reported standard errors of the truth, and the errors small."""
    for name, value in truth.items():
        err, se = abs(result.estimate[name] - value), result.stderr[name]
        assert 0 < se <= max_stderr, (name, se)
        assert err <= 3 * se, (name, result.estimate[name], value, se)


def test_coupled_initial_conditions_from_two_of_three_unknowns(solved):
    cb = solved("coupled").codebook
    truth = {"a": 0.3, "b": 0.7, "c": 0.45}
    data = synthetic("coupled", truth, np.linspace(0, 0.5, 41), ["u1", "u2"], noise=1e-3)
    result = pgdcli.fit(cb, data, sigma={"u1": 1e-3, "u2": 1e-3})
    assert result.success and set(result.estimate) == {"a", "b", "c"}
    assert_recovered(result, truth, max_stderr=5e-3)
    assert 0.7 < result.rms < 1.3  # residuals in units of sigma: the noise, not the model
    assert result.reference_error is not None and result.reference_error < 1e-7  # coupled's gate
    assert abs(result.reference_rms - result.rms) < 1e-3


def test_rigid_body_initial_velocities(solved):
    cb = solved("rigid_body").codebook
    truth = {"u10": 0.8, "u20": 1.3, "u30": 0.6, "w10": 1.1, "w20": 0.7, "w30": 1.4}
    data = synthetic("rigid_body", truth, np.linspace(0, 1, 31), ["u1", "u2", "u3", "w1", "w2", "w3"], noise=2e-3,
                     seed=1)
    result = pgdcli.fit(cb, data, starts=4)
    assert result.success
    assert_recovered(result, truth, max_stderr=5e-3)
    assert result.reference_error < 1e-4  # the rigid body's gate
    assert result.elapsed < 5.0


def test_linear_relaxation_rate_forcing_and_initial_value(solved):
    cb = solved("relaxation").codebook
    truth = {"k": 1.7, "a": 0.4, "u0": 0.65}
    data = synthetic("relaxation", truth, np.linspace(0, 3, 60), ["u"], noise=1e-3, seed=2)
    result = pgdcli.fit(cb, data)
    assert_recovered(result, truth, max_stderr=5e-3)
    assert result.reference_error < 1e-7


def test_fixed_and_known_coordinates(solved):
    cb = solved("relaxation").codebook
    truth = {"k": 2.5, "a": -0.3, "u0": 0.2}
    data = synthetic("relaxation", truth, np.linspace(0, 3, 40), ["u"], noise=1e-3, seed=3)
    held = pgdcli.fit(cb, data, fix={"u0": 0.2})
    assert set(held.estimate) == {"k", "a"} and held.fixed == {"u0": 0.2}
    assert_recovered(held, {"k": 2.5, "a": -0.3}, max_stderr=2e-2)  # k: the decay of a small u0
    known = pgdcli.fit(cb, {**data, "k": np.full(40, 2.5)}, starts=1)  # k as a (constant) data column
    assert set(known.estimate) == {"a", "u0"}
    assert_recovered(known, {"a": -0.3, "u0": 0.2}, max_stderr=5e-3)


def test_rows_at_different_known_coordinates(solved):
    """Rows of two experiments (k = 1 and k = 3) sharing a and u0: the point-by-point path."""
    cb = solved("relaxation").codebook
    truth = {"a": 0.5, "u0": 0.8}
    times = np.linspace(0, 3, 25)
    parts = [synthetic("relaxation", truth, times, ["u"], 1e-3, seed=s, extra={"k": k}) for s, k in ((4, 1.0), (5, 3.0))]
    data = {"t": np.concatenate([p["t"] for p in parts]), "u": np.concatenate([p["u"] for p in parts]),
            "k": np.repeat([1.0, 3.0], times.size)}
    result = pgdcli.fit(cb, data, starts=2)
    assert_recovered(result, truth, max_stderr=5e-3)
    assert result.reference_error < 1e-7


def _beyond_the_bound(solved):
    """Relaxation data whose initial value, 1.5, lies outside u0's domain [0, 1]."""
    data = synthetic("relaxation", {"k": 1.0, "a": 0.0, "u0": 1.0}, np.linspace(0, 3, 30), ["u"], noise=0, seed=0)
    data["u"] = data["u"] * 1.5
    return data


def test_estimate_at_a_bound_is_not_a_success(solved):
    cb = solved("relaxation").codebook
    result = pgdcli.fit(cb, _beyond_the_bound(solved), starts=2, check=False)
    assert "at the domain bound: " in result.message and "u0" in result.message
    assert result.estimate["u0"] == pytest.approx(1.0)
    assert result.at_bound == ["u0"] and result.bounds["u0"] == (0.0, 1.0)
    assert not result.success and result.to_dict()["success"] is False


def test_estimate_inside_the_domain_is_a_success(solved):
    cb = solved("relaxation").codebook
    data = synthetic("relaxation", {"k": 1.0, "a": 0.0, "u0": 0.7}, np.linspace(0, 3, 30), ["u"], noise=0, seed=0)
    result = pgdcli.fit(cb, data, starts=2, check=False)
    assert result.success and result.at_bound == [] and result.to_dict()["at_bound"] == []


def test_cli_estimate_at_a_bound_exits_1_with_one_warning(solved, tmp_path):
    path = tmp_path / "relaxation.h5"
    solved("relaxation").codebook.save(path)
    data = _beyond_the_bound(solved)
    csv = tmp_path / "d.csv"
    csv.write_text("t,u\n" + "".join(f"{t!r},{u!r}\n" for t, u in zip(map(float, data["t"]), map(float, data["u"]))))
    result = _run(["fit", path, csv, "--starts", "2", "--format", "json", "-q", "--no-check"])
    assert result.exit_code == 1, result.stderr
    report = json.loads(result.stdout)  # the output stands, marked
    assert report["success"] is False and report["at_bound"] == ["u0"]
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("Warning: fit: the estimate lies on its domain bound: u0 = 1 ")
    assert "domain [0, 1]" in lines[0] and "Traceback" not in result.stderr


# ----------------------------------------------------------------------------------------------
# data and usage errors: one line, exit 2
# ----------------------------------------------------------------------------------------------
def test_read_data_columns(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("t, u\n0, 1.5\n0.5,2\n\n")
    data = read_data(path)
    assert list(data) == ["t", "u"] and data["u"].tolist() == [1.5, 2.0]


@pytest.fixture(scope="module")
def coupled_file(tmp_path_factory, solved):
    path = tmp_path_factory.mktemp("fit") / "coupled.h5"
    solved("coupled").codebook.save(path)
    return path


def _run(args, stdin=None):
    return CliRunner().invoke(cli, [str(a) for a in args], prog_name="pgd", input=stdin)


@pytest.mark.parametrize("text, extra, needle", [
    ("", [], "empty file"),
    ("t,u1\n", [], "no data rows"),
    ("t,u1\n0.1,nan\n0.2,1\n", [], "line 2, column 'u1' is nan"),
    ("t,u1\n0.1,1\n0.2,\n", [], "line 3, column 'u1': '' is not a number"),
    ("u1,u2\n0.1,1\n", [], "no column for the time coordinate 't'"),
    ("t,a\n0.1,0.2\n0.2,0.2\n", [], "no observed unknown"),
    ("t,u1,w\n0.1,1,2\n", [], "column 'w' is neither"),
    ("t,u1\n0.1,1\n0.7,1\n", [], "column 't': value 0.7 is outside the domain [0, 0.5]"),
    ("t,u1\n0.1,1\n0.2,1\n", [], "2 data values for 3 free coordinates"),
    ("t,u1\n0.1,1\n0.2,1\n", ["--fix", "c=1.5"], "--fix c=1.5: outside the domain [0, 1]"),
    ("t,u1\n0.1,1\n0.2,1\n", ["--fix", "q=0.5"], "--fix q: unknown coordinate"),
    ("t,u1\n0.1,1\n0.2,1\n", ["--fix", "t=0.5"], "'t' is already a data column"),
    ("t,u1\n0.1,1\n0.2,1\n", ["--fix", "a=0.1,b=0.2,c=0.3"], "nothing to fit"),
    ("t,u1\n0.1,1\n0.2,1\n", ["--fix", "a"], "expected NAME=VALUE"),
    ("t,u1\n0.1,1\n0.2,1\n", ["--sigma", "u2=1"], "--sigma u2: not an observed unknown"),
    ("t,u1,sigma_u1\n0.1,1,0\n0.2,1,1\n", [], "sigma_u1 must be positive"),
])
def test_bad_input_is_one_line_exit_2(coupled_file, text, extra, needle):
    result = _run(["fit", coupled_file, "-", *extra], stdin=text)
    assert result.exit_code == 2, (result.exit_code, result.stderr)
    assert result.stdout == "" and "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and needle in lines[0], lines


def test_cli_formats_and_plot(coupled_file, tmp_path):
    data = synthetic("coupled", {"a": 0.2, "b": 0.5, "c": 0.9}, np.linspace(0, 0.5, 21), ["u1", "u3"], noise=1e-3)
    path = tmp_path / "d.csv"
    path.write_text("t,u1,u3\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in
                                         zip(*(map(float, data[k]) for k in ("t", "u1", "u3")))))
    plain = _run(["fit", coupled_file, path, "--starts", "2", "--plot", tmp_path / "f.png"])
    assert plain.exit_code == 0, plain.stderr
    rows = [line.split() for line in plain.stdout.splitlines()]
    assert [r[0] for r in rows] == ["a", "b", "c"] and all(len(r) == 3 for r in rows)
    assert abs(float(rows[2][1]) - 0.9) <= 3 * float(rows[2][2])
    assert "reference check at the estimate" in plain.stderr
    assert (tmp_path / "f.png").stat().st_size > 10000
    report = json.loads(_run(["fit", coupled_file, path, "--starts", "2", "--format", "json", "-q"]).stdout)
    assert set(report["estimate"]) == {"a", "b", "c"} and report["observed"] == ["u1", "u3"]
    assert len(report["fitted"]["u2"]) == 21 and report["reference_error"] < 1e-7
    table = _run(["fit", coupled_file, path, "--starts", "1", "--format", "csv", "-q", "--no-check"]).stdout
    assert table.splitlines()[0] == "t,u1,u1_data,u2,u3,u3_data" and len(table.splitlines()) == 22


def test_unidentifiable_coordinates_get_infinite_standard_errors(solved):
    """Data at t = 0 only see u0: k and a are not determined, and the fit says so."""
    cb = solved("relaxation").codebook
    data = {"t": np.zeros(5), "u": np.full(5, 0.3) + np.random.default_rng(9).normal(0, 1e-3, 5)}
    result = pgdcli.fit(cb, data, starts=1)
    assert np.isinf(result.stderr["k"]) and np.isinf(result.stderr["a"])
    assert 0 < result.stderr["u0"] < 1e-3  # u0 is what t = 0 measures
    assert result.to_dict()["stderr"]["k"] is None and result.to_dict()["stderr"]["a"] is None
    assert abs(result.estimate["u0"] - 0.3) < 2e-3 and result.reference_error < 1e-7


def test_reference_check_with_a_varying_parameter_column(solved):
    """Rows at one time and several known k (the varying data coordinate is not time)."""
    cb = solved("relaxation").codebook
    k = np.linspace(0.5, 5, 12)
    parts = [synthetic("relaxation", {"a": 0.5, "u0": 0.8}, np.array([1.0]), ["u"], 1e-4, seed=i, extra={"k": kk})
             for i, kk in enumerate(k)]
    data = {"t": np.ones(k.size), "k": k, "u": np.concatenate([p["u"] for p in parts])}
    result = pgdcli.fit(cb, data, starts=2)
    assert_recovered(result, {"a": 0.5, "u0": 0.8}, max_stderr=5e-3)
    assert result.reference_error < 1e-7 and abs(result.reference_rms - result.rms) < 1e-6


def _stream(*parts, repeat: int = 1):
    """A file-like object yielding ``parts`` then ``repeat`` copies of the last one, never held whole."""
    import io

    class Endless(io.RawIOBase):
        def __init__(self):
            self.chunks = iter(list(parts[:-1]) + [parts[-1]] * repeat)
            self.left = b""

        def readable(self):
            return True

        def readinto(self, buffer):
            while not self.left:
                self.left = next(self.chunks, None)
                if self.left is None:
                    return 0
            n = min(len(buffer), len(self.left))
            buffer[:n] = self.left[:n]
            self.left = self.left[n:]
            return n

    return io.BufferedReader(Endless())


@pytest.mark.parametrize("parts, repeat, needle", [
    ((b"\n" * 2**20,), 1024, "more than 1000 lines"),  # a gigabyte of blank lines
    ((b"t,u1\n", b"0.1,1\n" * 2**16), 2**10, "more than 1000 lines"),  # rows past the limit
    ((b"a," * 2**20 + b"a\n",), 1, "line 1: longer than 65536 bytes"),  # a million columns
    ((b"\0" * 2**20,), 1024, "line 1: longer than 65536 bytes"),  # a gigabyte without a newline
])
def test_huge_data_is_refused_while_streaming(monkeypatch, parts, repeat, needle):
    import time

    monkeypatch.setenv("PGD_QUERY_MAX_POINTS", "1000")
    started = time.process_time()
    with pytest.raises(FitError, match=needle):
        read_data(_stream(*parts, repeat=repeat), label="DATA (stdin)")
    assert time.process_time() - started < 2.0


def test_streamed_data_equals_the_columns(tmp_path):
    path = tmp_path / "data.csv"
    path.write_text("t, u1 ,sigma_u1\n\n0.1,1.5,0.01\n , \n0.2,-2e-3,0.02\n")
    data = read_data(path)
    assert list(data) == ["t", "u1", "sigma_u1"]
    assert data["t"].tolist() == [0.1, 0.2] and data["u1"].tolist() == [1.5, -2e-3]


def test_plot_without_matplotlib_is_one_error_line_before_the_fit(coupled_file, tmp_path):
    import subprocess
    import sys

    code = ("import sys; sys.modules['matplotlib'] = None  # as if not installed\n"
            "from pgdcli.cli.entry import main\nmain(sys.argv[1:])\n")
    data = tmp_path / "d.csv"
    data.write_text("t,u1\n0.1,1\n0.2,1.1\n0.3,1.2\n0.4,1.3\n")
    r = subprocess.run([sys.executable, "-c", code, "fit", str(coupled_file), str(data), "--plot",
                        str(tmp_path / "f.png")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stdout == "" and "Traceback" not in r.stderr
    assert r.stderr.splitlines() == ["Error: pgd fit --plot needs matplotlib, which is not installed: "
                                     "pip install 'pgdcli[plot]' (or pip install matplotlib)"]
