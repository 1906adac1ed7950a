"""``pgd plot --kind phase`` and ``--kind sensitivity``, the default kind, and what markers mean.

The data handed to matplotlib is checked against the codebook (``evaluate``, ``gradient``,
``sensitivity``), the reference against the exact solution; the pictures against their data.
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.backends.backend_agg import FigureCanvasAgg

from pgdcli import plot as P
from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook
from pgdcli.errors import QueryError

from conftest import EXACT


@pytest.fixture(scope="module")
def spring(codebook_path):
    path = codebook_path("spring")
    return Codebook.load(path), path


def _exact_reference(name):
    def solve(params, times):
        from types import SimpleNamespace

        grids = {k: np.asarray(v, dtype=float)[:, None] for k, v in params.items()}
        values = EXACT[name]({**grids, "t": np.asarray(times)[None, :]})
        size = len(next(iter(params.values())))
        return SimpleNamespace(values=values, success=np.ones(size, bool), messages=[""] * size)

    solve.description = "exact solution"
    return solve


def test_phase_data_is_one_unknown_against_another_along_time(spring):
    cb, _ = spring
    data = P.phase_data(cb, "x", "v", at=["k=1.5", "k=3,c=0.2"], points=41, reference=_exact_reference("spring"))
    assert data["x"] == "x" and data["y"] == "v" and data["xs"].shape == (2, 41)
    for i, p in enumerate(data["points"]):
        values = cb.evaluate({**p, "t": data["t"]})
        np.testing.assert_array_equal(data["xs"][i], values["x"])
        np.testing.assert_array_equal(data["ys"][i], values["v"])
    exact = EXACT["spring"]({"t": data["reference"]["t"], "k": 3.0, "c": 0.2})
    np.testing.assert_allclose(data["reference"]["ys"][1], exact["v"], atol=1e-14)
    fig = P.draw_phase(data)
    ax = fig.axes[0]
    curves = [ln for ln in ax.get_lines() if ln.get_label() in data["labels"]]
    assert [ln.get_marker() for ln in curves] == ["None", "None"]  # codebook curves: lines only
    np.testing.assert_array_equal(curves[1].get_xdata(), data["xs"][1])
    references = [ln for ln in ax.get_lines() if ln.get_label() == "_reference"]
    assert all(ln.get_linestyle() == "None" and ln.get_markerfacecolor() == "none" for ln in references)


def test_phase_against_a_rate_is_the_exact_derivative(codebook_path):
    """One unknown: by default against its own rate, d u / d t from the interpolant's derivative."""
    cb = Codebook.load(codebook_path("relaxation"))
    data = P.phase_data(cb, at="k=2,a=0.5,u0=0.3", points=31)
    assert (data["x"], data["y"]) == ("u", "du/dt")
    p = {"k": 2.0, "a": 0.5, "u0": 0.3, "t": data["t"]}
    exact_rate = -p["k"] * EXACT["relaxation"](p)["u"] + p["a"] * np.sin(2 * data["t"])  # the equation
    np.testing.assert_allclose(data["ys"][0], exact_rate, atol=1e-7)
    with pytest.raises(QueryError, match="rates"):
        P.phase_data(cb, "u", "der(u)", reference=_exact_reference("relaxation"))
    with pytest.raises(QueryError, match="--y: unknown 'w'"):
        P.phase_data(cb, "u", "w")
    with pytest.raises(QueryError, match="two different quantities"):
        P.phase_data(cb, "u", "u")


def test_sensitivity_plot_data_is_the_codebook_s(spring):
    cb, _ = spring
    data = P.sensitivity_data(cb, "v", points=21, at={"c": 0.3})
    s = cb.sensitivity(times=np.linspace(0, 4, 21), at={"c": 0.3}, fields=["v"])
    assert data["inputs"] == ["k"] == s.inputs
    np.testing.assert_array_equal(data["first"], s.first["v"])
    np.testing.assert_array_equal(data["std"], np.sqrt(s.variance["v"]))
    fig = P.draw_sensitivity(data)
    lower = fig.axes[1]
    first = [ln for ln in lower.get_lines() if ln.get_label() == "k: first order"][0]
    np.testing.assert_array_equal(first.get_ydata(), data["first"][:, 0])
    assert "c=0.3" in fig._suptitle.get_text()


def test_error_maximum_marker_lies_inside_the_frame(spring, tmp_path):
    cb, _ = spring
    for kwargs in ({"at": ["k=4,c=0.5"]}, {"over": "k,c", "fix": ["t=4"]}):
        data = P.error_data(cb, "x", reference=_exact_reference("spring"), points=15, **kwargs)
        # the largest error in a corner of the frame, where a marker drawn as it is would stick out
        data["values"][-1, -1] = data["max"] = 10 * data["max"]
        if "at" in kwargs:
            data["argmax"] = {**data["points"][-1], "t": float(data["t"][-1])}
        else:
            data["argmax"] = {data["x"]: float(data["xv"][-1]), data["y"]: float(data["yv"][-1]), **data["fixed"]}
        fig = P.draw_error(data)
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        ax = fig.axes[0]
        marker = [ln for ln in ax.get_lines() if ln.get_label().startswith("max ")][0]
        assert marker.get_marker() == "X"
        frame = ax.get_window_extent()
        box = marker.get_window_extent(canvas.get_renderer())
        assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1, (frame, box)
        if "at" in kwargs:  # error curves are lines; the one marker is the maximum
            assert [ln.get_marker() for ln in ax.get_lines() if not ln.get_label().startswith("max ")] == ["None"]


def test_solution_curves_carry_no_markers(spring):
    cb, _ = spring
    fig = P.draw_solution(P.solution_data(cb, at=["k=1.5", "k=3"]))
    assert {ln.get_marker() for ln in fig.axes[0].get_lines()} == {"None"}


def _run(*args):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def test_cli_default_kind_is_the_solution_and_options_choose_theirs(spring, tmp_path):
    _, path = spring
    r = _run("plot", str(path), "-o", str(tmp_path / "s.png"))
    assert r.exit_code == 0 and r.stdout == f"{tmp_path / 's.png'}\n"
    r = _run("plot", str(path))
    assert r.exit_code == 0 and r.stdout == f"{path.with_name('spring-solution.png')}\n"
    r = _run("plot", str(path), "--x", "x", "--y", "v", "--at", "k=2", "--reference", "-o", str(tmp_path / "p.svg"))
    assert r.exit_code == 0, r.stderr
    r = _run("plot", str(path), "--kind", "sensitivity", "--density", "k=normal:2,0.5", "--at", "c=0.2",
             "-o", str(tmp_path / "q.png"))
    assert r.exit_code == 0, r.stderr


@pytest.mark.parametrize("args, message", [
    (["--kind", "phase", "--x", "w"], "--x: unknown 'w'"),
    (["--kind", "sensitivity", "--over", "k,c"], "--over does not apply to --kind sensitivity"),
    (["--kind", "solution", "--x", "x"], "--x does not apply to --kind solution"),
    (["--kind", "sensitivity", "--density", "k=gamma:1"], "--density k=gamma:1: expected uniform"),
    (["--kind", "sensitivity", "--density", "k"], "expected NAME=SPEC"),
    (["--kind", "sensitivity", "--at", "k=2,k=3"], "'k' given twice"),
])
def test_cli_errors_of_the_new_kinds(spring, args, message):
    _, path = spring
    r = CliRunner().invoke(cli, ["plot", str(path), *args], catch_exceptions=False)
    assert r.exit_code == 2 and r.stdout == ""
    assert len(r.stderr.splitlines()) == 1 and message in r.stderr, r.stderr
