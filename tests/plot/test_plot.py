"""Tests of pgdcli.plot and ``pgd plot``.

The data handed to matplotlib is checked against the codebook (not pixels):
mode curves at the nodes are the stored mode matrices, solution curves and maps
are ``codebook.evaluate`` values, error data are ``|codebook - reference|``.
Every kind is rendered for every shipped problem to a PNG whose IHDR size is
checked, and to an SVG that is parsed; the CLI's exit codes and one-line errors
are checked with click's CliRunner.

Tensor-train codebooks (the nonlinear time march: coupled.yaml, logistic.yaml):
their HOSVD modes are checked against numpy's SVD of the unfoldings of
``Codebook.nodal_values``, and the march convergence figure against the
report's ``step_sizes`` and ``node_ranks``.
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.linalg import subspace_angles

from pgdcli import plot as P
from pgdcli.plot import draw, files, options
from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook
from pgdcli.errors import PgdError, QueryError

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ("parametric", "relaxation", "spring")
MARCHED = ("coupled", "logistic")  # nonlinear: time march, tensor-train codebooks


# ----------------------------------------------------------------------------------------------
# fixtures: the shipped problems solved once per test run, and exact references
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="session")
def plot_codebooks(tmp_path_factory):
    """name -> (Codebook, Path of its saved file), the shipped problems solved once."""
    from pgdcli import load_spec, solve

    directory = tmp_path_factory.mktemp("plot-codebooks")
    out = {}
    for name in SHIPPED:
        result = solve(load_spec(ROOT / "problems" / f"{name}.yaml"))
        assert result.converged
        path = result.codebook.save(directory / f"{name}.h5")
        out[name] = (Codebook.load(path), path)
    return out


def _exact(name: str, p: dict, t: np.ndarray) -> dict:
    """Exact solutions from the comments of problems/*.yaml; p values (S, 1), t (1, T)."""
    if name == "parametric":
        return {"u": (10.0 / p["k"] - 1.0) * t}
    if name == "relaxation":
        k, a, u0 = p["k"], p["a"], p["u0"]
        e = np.exp(-k * t)
        return {"u": u0 * e + a * (k * np.sin(2 * t) - 2 * np.cos(2 * t) + 2 * e) / (k * k + 4.0)}
    k, c = p["k"], p["c"]
    wd = np.sqrt(k - c * c / 4.0)
    decay = np.exp(-c * t / 2.0)
    return {"x": decay * (np.cos(wd * t) + c / (2.0 * wd) * np.sin(wd * t)),
            "v": -decay * (k / wd) * np.sin(wd * t)}


def exact_reference(name: str, calls: list | None = None):
    """A reference callable with solve_reference's interface, from the exact solution."""

    def solve(params, times):
        params = {k: np.asarray(v, dtype=float) for k, v in params.items()}
        S = len(next(iter(params.values())))
        if calls is not None:
            calls.append((params, np.asarray(times)))
        values = _exact(name, {k: v[:, None] for k, v in params.items()}, np.asarray(times)[None, :])
        values = {u: np.broadcast_to(v, (S, len(times))).copy() for u, v in values.items()}
        return SimpleNamespace(values=values, success=np.ones(S, bool), messages=[""] * S)

    solve.description = "exact"
    return solve


def _line_data(ax) -> list[np.ndarray]:
    """xy data of the labelled lines of an axes (legend entries), in drawing order."""
    return [ln.get_xydata() for ln in ax.get_lines() if not ln.get_label().startswith("_")]


# ----------------------------------------------------------------------------------------------
# modes
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", SHIPPED)
def test_modes_data_equals_stored_modes_at_the_nodes(plot_codebooks, name):
    cb, _ = plot_codebooks[name]
    for field in cb.unknown_names:
        data = P.modes_data(cb, field=field)
        fm = cb.fields[field]
        n = min(6, fm.rank)
        assert data["count"] == n and data["field"] == field and data["rank"] == fm.rank
        np.testing.assert_array_equal(data["alphas"], fm.weights[:n])
        assert [p["coordinate"] for p in data["panels"]] == cb.coordinate_names
        for c, m, panel in zip(cb.coordinates, fm.factors, data["panels"]):
            x = panel["x"]
            assert x[0] == c.domain[0] and x[-1] == c.domain[1] and np.all(np.diff(x) > 0)
            assert x.size > c.nodes  # a fine grid, not only the nodes
            nodes = c.basis().nodes
            idx = np.searchsorted(x, nodes)
            np.testing.assert_array_equal(x[idx], nodes)
            np.testing.assert_array_equal(panel["values"][idx], m[:, :n])  # exact at the nodes
            np.testing.assert_array_equal(panel["node_values"], m[:, :n])
            # between nodes: the codebook's own interpolant
            np.testing.assert_allclose(panel["values"], c.basis().interpolate(m[:, :n], x), rtol=0, atol=1e-14)


@pytest.mark.parametrize("name", ["relaxation", "spring"])
def test_all_mode_curves_reassemble_the_codebook(plot_codebooks, name):
    """sum_i alpha_i prod_j U_ij(x_j) over the plotted curves equals codebook(x) off the nodes."""
    cb, _ = plot_codebooks[name]
    field = cb.unknown_names[-1]
    data = P.modes_data(cb, count=10_000, field=field, points=57)
    assert data["count"] == cb.fields[field].rank
    rng = np.random.default_rng(5)
    picks = [rng.integers(0, p["x"].size, 40) for p in data["panels"]]
    prod = np.prod([p["values"][i] for p, i in zip(data["panels"], picks)], axis=0)
    assembled = prod @ data["alphas"]
    coords = {p["coordinate"]: p["x"][i] for p, i in zip(data["panels"], picks)}
    expected = cb.evaluate(coords, fields=[field])[field]
    np.testing.assert_allclose(assembled, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())


def test_modes_figure_draws_the_data(plot_codebooks):
    cb, _ = plot_codebooks["spring"]
    data = P.modes_data(cb, count=4, field="v")
    fig = P.draw_modes(data)
    axes = [ax for ax in fig.axes if ax.get_visible()]
    assert len(axes) == 3
    for ax, panel in zip(axes, data["panels"]):
        lines = _line_data(ax)
        assert len(lines) == 4
        for i, xy in enumerate(lines):
            np.testing.assert_array_equal(xy[:, 0], panel["x"])
            np.testing.assert_array_equal(xy[:, 1], panel["values"][:, i])
        assert ax.get_xlabel().startswith(panel["coordinate"])
        assert "v" in ax.get_ylabel()
    assert "spring" in fig._suptitle.get_text()
    # curves differ in line style and marker as well as color (grayscale)
    styles = {(ln.get_linestyle(), ln.get_marker()) for ln in axes[0].get_lines() if not ln.get_label().startswith("_")}
    assert len(styles) == 4


def test_modes_count_and_field_errors(plot_codebooks):
    cb, _ = plot_codebooks["spring"]
    assert P.modes_data(cb)["field"] == "x"  # default: the first unknown
    with pytest.raises(QueryError, match="--count"):
        P.modes_data(cb, count=0)
    with pytest.raises(QueryError, match=r"--field: unknown 'w'; this codebook has x, v"):
        P.modes_data(cb, field="w")


# ----------------------------------------------------------------------------------------------
# convergence
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", SHIPPED)
def test_convergence_data_is_the_report(plot_codebooks, name):
    cb, _ = plot_codebooks[name]
    data = P.convergence_data(cb)
    np.testing.assert_array_equal(data["residual"], cb.report["residual_history"])
    np.testing.assert_array_equal(data["modes"], np.arange(len(cb.report["residual_history"])))
    assert data["tolerance"] == cb.report["tolerance"] and data["converged"]
    assert data["outer"] is None
    fig = P.draw_convergence(data)
    assert len(fig.axes) == 1
    ax = fig.axes[0]
    assert ax.get_yscale() == "log"
    xy = ax.get_lines()[0].get_xydata()
    np.testing.assert_array_equal(xy[:, 0], data["modes"])
    np.testing.assert_array_equal(xy[:, 1], data["residual"])


def test_convergence_outer_history_when_present(plot_codebooks):
    cb0, _ = plot_codebooks["parametric"]
    report = dict(cb0.report, outer_history=np.array([1e-1, 1e-3, 1e-6, 0.0]))
    cb = Codebook(cb0.coordinates, cb0.fields, name="nonlinear", spec_text=cb0.spec_text, report=report)
    data = P.convergence_data(cb)
    np.testing.assert_array_equal(data["outer"]["iteration"], [1, 2, 3, 4])
    np.testing.assert_array_equal(data["outer"]["change"], report["outer_history"])
    fig = P.draw_convergence(data)
    assert len(fig.axes) == 2
    xy = fig.axes[1].get_lines()[0].get_xydata()
    np.testing.assert_array_equal(xy[:3, 1], [1e-1, 1e-3, 1e-6])
    assert np.isnan(xy[3, 1])  # a zero change is left off the log axis, not an error
    no_history = Codebook(cb0.coordinates, cb0.fields, name="bare", report={})
    with pytest.raises(PgdError, match="no residual history"):
        P.convergence_data(no_history)


# ----------------------------------------------------------------------------------------------
# solution
# ----------------------------------------------------------------------------------------------
def test_solution_lines_equal_codebook_values(plot_codebooks):
    cb, _ = plot_codebooks["spring"]
    data = P.solution_data(cb, "v", at=["k=3.2", "k=1.5,c=0.1", {"c": 0.45}])
    assert data["layout"] == "lines" and data["time"] == "t"
    assert data["points"] == [{"k": 3.2, "c": 0.3}, {"k": 1.5, "c": 0.1}, {"k": 2.5, "c": 0.45}]  # midpoints
    t = data["t"]
    assert t[0] == 0.0 and t[-1] == 4.0 and t.size == options.LINE_POINTS
    for p, row in zip(data["points"], data["values"]):
        np.testing.assert_array_equal(row, cb(t=t, **p)["v"])
    fig = P.draw_solution(data)
    ax = fig.axes[0]
    for xy, row in zip(_line_data(ax), data["values"]):
        np.testing.assert_array_equal(xy[:, 0], t)
        np.testing.assert_array_equal(xy[:, 1], row)
    assert ax.get_xlabel() == "t" and ax.get_ylabel() == "v"
    assert [tx.get_text() for tx in fig.legends[0].get_texts()] == data["labels"] == [
        "k=3.2, c=0.3", "k=1.5, c=0.1", "k=2.5, c=0.45"]


def test_solution_default_points_span_the_first_parameter(plot_codebooks):
    cb, _ = plot_codebooks["relaxation"]
    data = P.solution_data(cb)
    ks = [p["k"] for p in data["points"]]
    np.testing.assert_allclose(ks, np.linspace(0.5, 5, options.DEFAULT_AT_CURVES))
    assert all(p["a"] == 0.0 and p["u0"] == 0.5 for p in data["points"])


def test_solution_map_equals_codebook_values(plot_codebooks):
    cb, _ = plot_codebooks["spring"]
    data = P.solution_data(cb, "x", over="k,t", fix=["c=0.2"], points=23)
    assert data["layout"] == "map" and (data["x"], data["y"]) == ("k", "t") and data["fixed"] == {"c": 0.2}
    xv, yv, z = data["xv"], data["yv"], data["values"]
    assert z.shape == (yv.size, xv.size) == (23, 23)
    for j in (0, 7, 22):
        for i in (0, 11, 22):
            np.testing.assert_allclose(z[j, i], cb(k=xv[i], t=yv[j], c=0.2)["x"], rtol=1e-14, atol=1e-14)
    fig = P.draw_solution(data)
    ax = fig.axes[0]
    mesh = ax.collections[0]
    np.testing.assert_array_equal(np.asarray(mesh.get_array()).reshape(z.shape), z)
    assert ax.get_xlabel() == "k" and ax.get_ylabel() == "t"
    # defaults: the other coordinates at their midpoints
    assert P.solution_data(cb, over="c,k", points=5)["fixed"] == {"t": 2.0}


def test_solution_reference_markers(plot_codebooks):
    cb, _ = plot_codebooks["relaxation"]
    calls = []
    data = P.solution_data(cb, at=["k=1,a=0.5", "k=4"], reference=exact_reference("relaxation", calls))
    ref = data["reference"]
    assert ref["t"].size == options.REFERENCE_MARKERS and ref["values"].shape == (2, options.REFERENCE_MARKERS)
    params, times = calls[0]
    assert set(params) == {"k", "a", "u0"}  # every non-time coordinate, never t
    np.testing.assert_array_equal(params["k"], [1.0, 4.0])
    np.testing.assert_array_equal(params["u0"], [0.5, 0.5])
    np.testing.assert_array_equal(times, ref["t"])
    fig = P.draw_solution(data)
    markers = [ln for ln in fig.axes[0].get_lines() if ln.get_linestyle() == "None"]
    assert len(markers) == 2
    for ln, row in zip(markers, ref["values"]):
        np.testing.assert_array_equal(ln.get_ydata(), row)


def test_solution_map_with_reference_is_on_the_same_grid(plot_codebooks):
    cb, _ = plot_codebooks["parametric"]
    data = P.solution_data(cb, over="t,k", points=9, reference=exact_reference("parametric"))
    exact = (10.0 / data["yv"][:, None] - 1.0) * data["xv"][None, :]
    np.testing.assert_allclose(data["reference"]["values"], exact, rtol=0, atol=1e-12)
    np.testing.assert_allclose(data["values"], exact, rtol=0, atol=1e-11)
    P.draw_solution(data)


@pytest.mark.parametrize("kwargs, message", [
    (dict(at=["k=12"]), r"--at k=12: outside the domain \[1, 4\]"),
    (dict(at=["k"]), r"--at: expected NAME=VALUE"),
    (dict(at=["k="]), r"--at: missing value for coordinate 'k'"),
    (dict(at=["k=abc"]), r"--at k=abc: not a number"),
    (dict(at=["z=1"]), r"--at: unknown coordinate 'z'; this codebook has t in \[0, 4\], k in \[1, 4\]"),
    (dict(at=["k=1,k=2"]), r"--at: coordinate 'k' given twice"),
    (dict(at=["t=1"]), r"--at: 't' is the time axis"),
    (dict(at=["k=2"], over="t,k"), r"--at and --over"),
    (dict(over="k"), r"--over: expected two different coordinate names"),
    (dict(over="k,k"), r"--over: expected two different coordinate names"),
    (dict(over="k,q"), r"--over: unknown coordinate 'q'"),
    (dict(over="t,k", fix=["k=2"]), r"--fix: 'k' is an axis of the map"),
    (dict(over="t,k", fix=["c=9"]), r"--fix c=9: outside the domain"),
    (dict(fix=["c=0.2"]), r"--fix applies to maps"),
    (dict(points=1), r"--points: expected an integer from 2 to 100000"),
    (dict(over="k,c", points=5000), r"--points: expected an integer from 2 to 1000"),
])
def test_solution_option_errors(plot_codebooks, kwargs, message):
    cb, _ = plot_codebooks["spring"]
    with pytest.raises(QueryError, match=message) as info:
        P.solution_data(cb, **kwargs)
    assert "\n" not in str(info.value)


# ----------------------------------------------------------------------------------------------
# error
# ----------------------------------------------------------------------------------------------
def test_error_lines_equal_abs_difference(plot_codebooks):
    cb, _ = plot_codebooks["spring"]
    data = P.error_data(cb, "x", at=["k=2,c=0.1", "k=4"], points=33, reference=exact_reference("spring"))
    assert data["layout"] == "lines" and data["values"].shape == (2, 33)
    t = data["t"]
    for p, err, cbv, ref in zip(data["points"], data["values"], data["codebook"], data["reference"]):
        np.testing.assert_array_equal(cbv, cb(t=t, **p)["x"])
        exact = _exact("spring", {k: np.array(v) for k, v in p.items()}, t)["x"]
        np.testing.assert_array_equal(ref, exact)
        np.testing.assert_array_equal(err, np.abs(cbv - exact))
    assert data["max"] == data["values"].max()
    i, j = np.unravel_index(np.argmax(data["values"]), data["values"].shape)
    assert data["argmax"] == {**data["points"][i], "t": t[j]}
    assert data["max"] < 1e-7
    fig = P.draw_error(data)
    ax = fig.axes[0]
    assert ax.get_yscale() == "log"
    for xy, err in zip(_line_data(ax), data["values"]):
        np.testing.assert_array_equal(xy[:, 1], np.where(err > 0, err, np.nan))


@pytest.mark.parametrize("over, fix", [(None, None), ("k,c", ["t=3"]), ("a,t", ["k=2,u0=0"])])
def test_error_map_equals_abs_difference(plot_codebooks, over, fix):
    cb, _ = plot_codebooks["relaxation" if over != "k,c" else "spring"]
    name = cb.name
    field = cb.unknown_names[0]
    data = P.error_data(cb, over=over, fix=fix, points=17, reference=exact_reference(name))
    assert data["layout"] == "map"
    if over is None:  # default: time along x, the first parameter along y
        assert (data["x"], data["y"]) == ("t", "k")
    gx, gy = np.meshgrid(data["xv"], data["yv"])
    coords = {data["x"]: gx, data["y"]: gy, **{k: np.full(gx.shape, v) for k, v in data["fixed"].items()}}
    cbv = cb.evaluate(coords, fields=[field])[field]
    t = coords.pop("t")
    exact = _exact(name, coords, t)[field]
    np.testing.assert_array_equal(data["codebook"], cbv)
    np.testing.assert_allclose(data["reference"], exact, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(data["values"], np.abs(data["codebook"] - data["reference"]))
    j, i = np.unravel_index(np.argmax(data["values"]), data["values"].shape)
    assert data["argmax"][data["x"]] == data["xv"][i] and data["argmax"][data["y"]] == data["yv"][j]
    fig = P.draw_error(data)
    assert fig.axes[0].collections[0].norm.__class__.__name__ == "LogNorm"


def test_reference_failures_become_nan_and_messages(plot_codebooks):
    cb, _ = plot_codebooks["parametric"]
    good = exact_reference("parametric")

    def flaky(params, times):
        r = good(params, times)
        r.success[1] = False
        r.values["u"][1] = np.nan
        r.messages[1] = "integration failed at t = 3: step size too small"
        return r

    data = P.error_data(cb, at=["k=2", "k=5", "k=8"], points=11, reference=flaky)
    assert np.isnan(data["values"][1]).all() and np.isfinite(data["values"][[0, 2]]).all()
    assert data["failures"] == ["reference failed at k=5: integration failed at t = 3: step size too small"]
    P.draw_error(data)


def test_real_reference_agrees_with_the_exact_solution(plot_codebooks):
    """The default reference (pgdcli.checks.reference, solve_ivp) is wired with the right parameters."""
    pytest.importorskip("pgdcli.checks.reference")
    for name in ("relaxation", "spring"):
        cb, path = plot_codebooks[name]
        ref = P.reference_solver(cb, source=str(path))
        lines = P.error_data(cb, at=["k=1.2"], points=21, reference=ref)
        p = {k: np.array([v]) for k, v in lines["points"][0].items()}
        exact = _exact(name, {k: v[:, None] for k, v in p.items()}, lines["t"][None, :])[cb.unknown_names[0]]
        np.testing.assert_allclose(lines["reference"], exact, rtol=0, atol=1e-9)
        assert lines["max"] < 1e-7
        grid = P.error_data(cb, over=",".join(cb.coordinate_names[1:3]), points=9, reference=ref)
        assert grid["values"].shape == (9, 9) and grid["max"] < 1e-7 and not grid["failures"]


def test_codebook_with_time_as_the_only_coordinate(tmp_path):
    """No parameters: one curve, error along time, the reference called with no parameters."""
    pytest.importorskip("pgdcli.checks.reference")
    from pgdcli.codebook.codebook import CoordinateInfo, CPTensor

    c = CoordinateInfo("t", (0.0, 2.0), 14, "chebyshev", "time")
    nodes = c.basis().nodes
    spec = 'name: decay\ncoordinates:\n  t: {domain: [0, 2], nodes: 14}\nunknowns:\n  u: {initial: 1}\n' \
           'equations:\n  - "der(u) = -u"\n'
    cb = Codebook([c], {"u": CPTensor(np.array([1.0]), (np.exp(-nodes)[:, None],))}, name="decay",
                  spec_text=spec, report={"residual_history": np.array([1.0, 1e-9]), "tolerance": 1e-8})
    sol = P.solution_data(cb, reference=True)
    assert sol["points"] == [{}] and sol["labels"] == ["(no parameters)"]
    np.testing.assert_allclose(sol["reference"]["values"][0], np.exp(-sol["reference"]["t"]), atol=1e-11)
    err = P.error_data(cb)
    assert err["layout"] == "lines" and err["max"] < 1e-10
    with pytest.raises(QueryError, match="--over"):
        P.solution_data(cb, over="t,k")
    for fig in (P.plot_modes(cb), P.draw_solution(sol), P.draw_error(err)):
        P.save_figure(fig, tmp_path / "f.png")


# ----------------------------------------------------------------------------------------------
# files: PNG / SVG of the expected size
# ----------------------------------------------------------------------------------------------
def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def _svg_root(path: Path):
    root = ET.parse(path).getroot()
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    return root


@pytest.mark.parametrize("name", SHIPPED)
@pytest.mark.parametrize("kind", P.KINDS)
def test_render_png_of_the_expected_size(plot_codebooks, tmp_path, monkeypatch, name, kind):
    cb, path = plot_codebooks[name]
    # the error kind of the parametric problem exercises the real reference (if present)
    if kind == "error" and name != "parametric":
        monkeypatch.setattr(files, "reference_solver", lambda codebook, **kw: exact_reference(name))
    out = P.render(path, kind, tmp_path / f"{name}-{kind}.png", dpi=40, size=(5.5, 3.25))
    assert out == tmp_path / f"{name}-{kind}.png"
    assert _png_size(out) == (220, 130)


@pytest.mark.parametrize("kind", P.KINDS)
def test_render_svg_and_default_sizes(plot_codebooks, tmp_path, kind):
    cb, path = plot_codebooks["spring"]
    options = {"reference": True} if kind == "solution" else {}
    svg = P.render(path, kind, tmp_path / "figure.svg", size="6.5x4", **options)
    root = _svg_root(svg)
    assert root.get("width") == "468pt" and root.get("height") == "288pt"
    # default figure size per kind at the default dpi
    png = P.render(path, kind, tmp_path / "figure.png", **options)
    data = {"modes": P.modes_data(cb), "convergence": P.convergence_data(cb)}.get(kind)
    w, h = _png_size(png)
    if data is not None:
        fig = {"modes": P.draw_modes, "convergence": P.draw_convergence}[kind](data)
        fw, fh = fig.get_size_inches() * P.DEFAULT_DPI
        assert abs(w - fw) <= 1 and abs(h - fh) <= 1
    else:
        assert (w, h) == (round((8.4 if kind == "solution" else 7.0) * 150), round((4.6 if kind == "solution" else 5.2) * 150))


def test_save_figure_rejects_other_suffixes(plot_codebooks, tmp_path):
    cb, _ = plot_codebooks["parametric"]
    fig = P.plot_convergence(cb)
    with pytest.raises(PgdError, match=r"--output .*x\.pdf: unsupported file type '\.pdf'; expected a \.png or \.svg"):
        P.save_figure(fig, tmp_path / "x.pdf")
    with pytest.raises(PgdError, match="does not exist"):
        P.save_figure(fig, tmp_path / "missing" / "x.png")
    written = P.save_figure(fig, tmp_path / "UPPER.PNG")
    umask = os.umask(0)
    os.umask(umask)
    assert written.stat().st_mode & 0o777 == 0o666 & ~umask  # not mkstemp's 0600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["UPPER.PNG"]  # no temporary files left


def test_default_output_is_next_to_the_codebook():
    assert P.default_output("codebooks/spring.h5", "error") == Path("codebooks/spring-error.png")


# ----------------------------------------------------------------------------------------------
# the command line
# ----------------------------------------------------------------------------------------------
def _run(*args):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def test_cli_writes_and_prints_the_path(plot_codebooks, tmp_path):
    _, path = plot_codebooks["spring"]
    out = tmp_path / "s.svg"
    r = _run("plot", str(path), "--kind", "solution", "--at", "k=1.5", "--at", "k=3,c=0.1", "--field", "v",
             "-o", str(out))
    assert r.exit_code == 0, r.stderr
    assert r.stdout == f"{out}\n" and r.stderr == ""
    _svg_root(out)
    # default output: <codebook stem>-<kind>.png next to the codebook
    r = _run("plot", str(path), "--kind", "convergence")
    assert r.exit_code == 0 and r.stdout == f"{path.with_name('spring-convergence.png')}\n"
    assert _png_size(path.with_name("spring-convergence.png")) == (960, 630)


@pytest.mark.parametrize("args, message", [
    (["-o", "x.pdf"], "--output x.pdf: unsupported file type '.pdf'"),
    (["-o", "x"], "unsupported file type '(no suffix)'"),
    (["--kind", "solution", "--at", "k=12"], "--at k=12: outside the domain [1, 4] of 'k'"),
    (["--kind", "solution", "--at", "k"], "--at: expected NAME=VALUE[,NAME=VALUE...], got 'k'"),
    (["--kind", "error", "--at", "c="], "--at: missing value for coordinate 'c'"),
    (["--kind", "solution", "--at", "q=1"], "--at: unknown coordinate 'q'"),
    (["--field", "w"], "--field: unknown 'w'; this codebook has x, v"),
    (["--kind", "error", "--over", "k"], "--over: expected two different coordinate names"),
    (["--kind", "convergence", "--count", "3"], "--count does not apply to --kind convergence"),
    (["--kind", "error", "--reference"], "--reference does not apply to --kind error"),
    (["--kind", "modes", "--at", "k=2"], "--at does not apply to --kind modes"),
    (["--kind", "nope"], "Invalid value for '--kind'"),
    (["--size", "big"], "--size: expected WIDTHxHEIGHT"),
    (["--dpi", "0"], "--dpi: expected an integer between 10 and 1200"),
])
def test_cli_errors_are_one_line_exit_2(plot_codebooks, tmp_path, args, message):
    _, path = plot_codebooks["spring"]
    r = CliRunner().invoke(cli, ["plot", str(path), *args], catch_exceptions=False)
    assert r.exit_code == 2
    assert r.stdout == ""
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and message in lines[0], r.stderr
    assert not list(path.parent.glob("*.pdf"))


def test_cli_missing_codebook(tmp_path):
    r = _run("plot", str(tmp_path / "none.h5"))
    assert r.exit_code == 2 and r.stderr.startswith("Error: ") and "no such file" in r.stderr


def test_cli_needs_no_display_and_no_pyplot(plot_codebooks, tmp_path):
    """A fresh process without DISPLAY: the image is written and pyplot is never imported."""
    _, path = plot_codebooks["parametric"]
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MPLBACKEND")}
    code = ("import sys; from pgdcli.cli.entry import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "assert 'matplotlib.pyplot' not in sys.modules\n")
    out = tmp_path / "m.png"
    r = subprocess.run([sys.executable, "-c", code, "plot", str(path), "-o", str(out)], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == str(out)
    _png_size(out)


_WITHOUT_MATPLOTLIB = ("import sys; sys.modules['matplotlib'] = None  # as if not installed\n"
                       "from pgdcli.cli.entry import main\nmain(sys.argv[1:])\n")


def _without_matplotlib(*args, cwd=None):
    return subprocess.run([sys.executable, "-c", _WITHOUT_MATPLOTLIB, *map(str, args)], capture_output=True,
                          text=True, timeout=300, cwd=cwd)


def test_without_matplotlib_plotting_is_one_error_line_with_the_install_command(plot_codebooks, tmp_path,
                                                                              monkeypatch):
    _, path = plot_codebooks["parametric"]
    out = tmp_path / "new" / "m.png"
    r = _without_matplotlib("plot", path, "-o", out)
    assert r.returncode == 2 and r.stdout == "" and "Traceback" not in r.stderr
    assert r.stderr.splitlines() == ["Error: pgd plot needs matplotlib, which is not installed: "
                                     "pip install 'pgdcli[plot]' (or pip install matplotlib)"]
    assert not out.parent.exists()  # nothing made before the error
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # the Python API says the same
    with pytest.raises(PgdError, match=r"needs matplotlib, which is not installed: pip install 'pgdcli\[plot\]'"):
        P.plot_modes(plot_codebooks["parametric"][0])


def test_without_matplotlib_solve_query_verify_info_and_export_work(tmp_path):
    spec = tmp_path / "decay.yaml"
    spec.write_text("coordinates:\n  t: {domain: [0, 1]}\n  k: {domain: [0.5, 2]}\nunknowns:\n  u: {initial: 1}\n"
                    "equations:\n  - \"der(u) = -k*u\"\nsolver:\n  tolerance: 1e-8\n")
    book = tmp_path / "decay.h5"
    steps = [("solve", spec, "-o", book, "-q"), ("query", book, "--t", "0.5", "--k", "1"),
             ("verify", book, "-j", "1", "-q", "--samples", "4"), ("info", book), ("export", book, "--to", "c", "-q")]
    outputs = {}
    for args in steps:
        r = _without_matplotlib(*args)
        assert r.returncode == 0, (args, r.stderr)
        outputs[args[0]] = r.stdout
    assert abs(float(outputs["query"]) - np.exp(-0.5)) <= 1e-8  # u = exp(-k t)


# ----------------------------------------------------------------------------------------------
# tensor-train codebooks (time march): HOSVD modes and the march's convergence
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def march_codebooks(tmp_path_factory):
    """name -> (Codebook, Path): the nonlinear problems solved once per module (~1 s each), saved and
    loaded back, so the report arrays are those read from the file."""
    from pgdcli import load_spec, solve
    from pgdcli.codebook.codebook import TT

    directory = tmp_path_factory.mktemp("march-codebooks")
    out = {}
    for name in MARCHED:
        result = solve(load_spec(ROOT / "problems" / f"{name}.yaml"))
        assert result.converged and result.codebook.report["method"] == "march"
        path = result.codebook.save(directory / f"{name}.h5")
        cb = Codebook.load(path)
        assert all(isinstance(fm, TT) for fm in cb.fields.values())
        out[name] = (cb, path)
    return out


def _small_tt_codebook() -> Codebook:
    """A random tensor train over (t, p, q, s) with its cores in the order (p, t, s, q).

    p (piecewise linear, the first core, rank 3) has an unfolding of rank 3
    below its 7 nodes; q (the last core) has 3 nodes, below its rank 5; t has
    9 nodes below its core's 3 * 4 columns.
    """
    from pgdcli.codebook.codebook import CoordinateInfo, TT

    coords = [CoordinateInfo("t", (0.0, 2.0), 9, "chebyshev", "time"),
              CoordinateInfo("p", (-1.0, 3.0), 7, "linear", "parameter"),
              CoordinateInfo("q", (0.5, 1.5), 3, "chebyshev", "parameter"),
              CoordinateInfo("s", (0.0, 1.0), 6, "chebyshev", "parameter")]
    order = (1, 0, 3, 2)
    ranks = (1, 3, 4, 5, 1)
    rng = np.random.default_rng(11)
    cores = tuple(rng.standard_normal((ranks[k], coords[j].nodes, ranks[k + 1])) * (1.0 + k)
                  for k, j in enumerate(order))
    return Codebook(coords, {"w": TT(cores, order)}, name="small-tt", report={})


def _unfolding(full: np.ndarray, j: int) -> np.ndarray:
    return np.moveaxis(full, j, 0).reshape(full.shape[j], -1)


def _check_hosvd_panels(cb, field, data, atol_sigma=1e-12, atol_angle=1e-10):
    """Panels of modes_data against numpy's SVD of the unfoldings of the full nodal tensor."""
    full = cb.nodal_values(field)
    assert [p["coordinate"] for p in data["panels"]] == cb.coordinate_names
    for j, (c, panel) in enumerate(zip(cb.coordinates, data["panels"])):
        u_np, s_np, _ = np.linalg.svd(_unfolding(full, j), full_matrices=False)
        sigma = panel["singular_values"]
        m = sigma.size
        assert np.all(np.diff(sigma) <= 1e-12 * sigma[0])  # decreasing
        np.testing.assert_allclose(sigma, s_np[:m], rtol=0, atol=atol_sigma * s_np[0])
        np.testing.assert_allclose(s_np[m:], 0.0, atol=atol_sigma * s_np[0])  # nothing beyond the core's width
        threshold = max(_unfolding(full, j).shape) * np.finfo(float).eps * s_np[0]  # numpy's matrix_rank
        if not np.any(np.abs(s_np / threshold - 1.0) < 0.01):  # no singular value at the threshold
            assert panel["rank"] == np.linalg.matrix_rank(_unfolding(full, j))
        k = panel["count"]
        assert k <= min(data["count"], panel["rank"])
        vectors = panel["node_values"]
        assert vectors.shape == (c.nodes, k)
        np.testing.assert_allclose(vectors.T @ vectors, np.eye(k), rtol=0, atol=1e-12)  # normalized
        # the same subspace as numpy's leading k left singular vectors ...
        angles = subspace_angles(vectors, u_np[:, :k])
        assert angles.max() < atol_angle
        # ... and, where the singular values are well separated, the same vectors up to sign
        for i in range(k):
            gap = np.min(np.abs(np.delete(s_np, i) - s_np[i])) / s_np[0]
            if gap > 1e-6:
                assert abs(abs(vectors[:, i] @ u_np[:, i]) - 1.0) < 1e-9
            big = np.argmax(np.abs(vectors[:, i]))
            assert vectors[big, i] > 0  # sign convention
        # plotted curves: the vectors at the nodes, the codebook's interpolant between them
        x = panel["x"]
        nodes = c.basis().nodes
        idx = np.searchsorted(x, nodes)
        np.testing.assert_array_equal(x[idx], nodes)
        np.testing.assert_array_equal(panel["values"][idx], vectors)
        np.testing.assert_allclose(panel["values"], c.basis().interpolate(vectors, x), rtol=0, atol=1e-14)


def test_tt_hosvd_modes_equal_svd_of_the_unfoldings():
    cb = _small_tt_codebook()
    fm = cb.fields["w"]
    hosvd = P.tt_hosvd_modes(fm)
    assert sorted(hosvd) == [0, 1, 2, 3]
    widths = {j: min(cb.coordinates[j].nodes, fm.cores[k].shape[0] * fm.cores[k].shape[2])
              for k, j in enumerate(fm.mode_order)}
    for j, (u, s) in hosvd.items():
        assert u.shape == (cb.coordinates[j].nodes, widths[j]) and s.shape == (widths[j],)
    data = P.modes_data(cb, count=10, points=41)
    assert data["representation"] == "tensor-train" and data["alphas"] is None
    assert data["ranks"] == (3, 4, 5) and data["rank"] == 5
    _check_hosvd_panels(cb, "w", data)
    assert [p["rank"] for p in data["panels"]] == [9, 3, 3, 6]  # t, p, q, s: min(nodes, core columns)
    assert [p["singular_values"].size for p in data["panels"]] == [9, 3, 3, 6]
    assert [p["count"] for p in data["panels"]] == [9, 3, 3, 6]
    assert data["count"] == 9
    for j, panel in enumerate(data["panels"]):  # what is plotted at the nodes: tt_hosvd_modes' vectors
        np.testing.assert_array_equal(panel["node_values"], hosvd[j][0][:, :panel["count"]])
        np.testing.assert_array_equal(panel["singular_values"], hosvd[j][1])
    # count caps every panel
    small = P.modes_data(cb, count=2)
    assert [p["count"] for p in small["panels"]] == [2, 2, 2, 2]
    for a, b in zip(small["panels"], data["panels"]):
        np.testing.assert_array_equal(a["node_values"], b["node_values"][:, :2])


@pytest.mark.parametrize("name", MARCHED)
def test_march_modes_are_the_hosvd_of_the_nodal_values(march_codebooks, name):
    cb, _ = march_codebooks[name]
    field = cb.unknown_names[-1]
    data = P.modes_data(cb, field=field)
    assert data["field"] == field and data["count"] == 6
    _check_hosvd_panels(cb, field, data, atol_sigma=1e-11, atol_angle=1e-8)


def test_tt_modes_figure_draws_the_data(march_codebooks):
    cb, _ = march_codebooks["coupled"]
    data = P.modes_data(cb, count=4, field="u2")
    fig = P.draw_modes(data)
    axes = [ax for ax in fig.axes if ax.get_visible()]
    assert len(axes) == 4
    for ax, panel in zip(axes, data["panels"]):
        lines = _line_data(ax)
        assert len(lines) == panel["count"] == 4
        for i, xy in enumerate(lines):
            np.testing.assert_array_equal(xy[:, 0], panel["x"])
            np.testing.assert_array_equal(xy[:, 1], panel["values"][:, i])
        title = ax.get_title(loc="left")
        assert f"rank {panel['rank']}" in title and "\u03c3 = " in title
        assert draw._compact(panel["singular_values"][0]) in title
    legend = fig.legends[0]
    assert [t.get_text() for t in legend.get_texts()] == ["mode 1", "mode 2", "mode 3", "mode 4"]
    assert "normalized" in legend.get_title().get_text() and "HOSVD" in fig._suptitle.get_text()


def test_march_convergence_data_is_the_report(march_codebooks):
    for name in MARCHED:
        cb, _ = march_codebooks[name]
        rep = cb.report
        data = P.convergence_data(cb)
        assert data["method"] == "march" and data["time"] == "t"
        np.testing.assert_array_equal(data["step_sizes"], rep["step_sizes"])
        tc = cb.coordinates[0]
        np.testing.assert_array_equal(data["step_end"], tc.domain[0] + np.cumsum(rep["step_sizes"]))
        np.testing.assert_array_equal(data["step_start"][1:], data["step_end"][:-1])
        assert data["step_start"][0] == tc.domain[0]
        assert data["step_end"][-1] == pytest.approx(tc.domain[1], rel=1e-12)
        np.testing.assert_array_equal(data["node_times"], tc.basis().nodes)
        np.testing.assert_array_equal(data["node_ranks"], rep["node_ranks"])
        np.testing.assert_array_equal(data["ranks"], np.asarray(rep["node_ranks"]).max(axis=2))
        assert data["ranks"].shape == (tc.nodes, len(cb.unknown_names)) and data["unknowns"] == cb.unknown_names
        assert data["steps"] == rep["steps"] == data["step_sizes"].size
        assert data["rejected"] == rep["rejected_steps"]
        assert data["error_estimate"] == rep["error_estimate"] and data["tolerance"] == rep["tolerance"]
        assert data["check_error"] == rep["check_error"]
        assert data["converged"]


def test_march_convergence_figure_draws_the_data(march_codebooks):
    cb, _ = march_codebooks["coupled"]
    data = P.convergence_data(cb)
    fig = P.draw_convergence(data)
    ax1, ax2 = fig.axes
    (steps,) = _line_data(ax1)
    np.testing.assert_array_equal(steps[:, 0], data["step_end"])
    np.testing.assert_array_equal(steps[:, 1], data["step_sizes"])
    (stairs,) = ax1.patches
    values, edges, _ = stairs.get_data()
    np.testing.assert_array_equal(values, data["step_sizes"])
    np.testing.assert_array_equal(edges, np.concatenate([data["step_start"][:1], data["step_end"]]))
    lines = _line_data(ax2)
    assert len(lines) == len(data["unknowns"]) == 3
    for i, xy in enumerate(lines):
        np.testing.assert_array_equal(xy[:, 0], data["node_times"])
        np.testing.assert_array_equal(xy[:, 1], data["ranks"][:, i])
    labels = [t.get_text() for t in ax2.get_legend().get_texts()]
    assert labels[0] == "u1" and all(lab.startswith(u) for lab, u in zip(labels, data["unknowns"]))
    title = fig._suptitle.get_text()
    assert draw._sci(data["error_estimate"]) in title and draw._sci(data["tolerance"]) in title
    assert "tolerance 1e-9" in title and f"max error {draw._sci(data['check_error'])} vs scipy" in title
    assert f"{data['steps']} accepted steps" in ax1.get_title(loc="left")


def test_march_convergence_edge_cases(march_codebooks):
    cb0, _ = march_codebooks["logistic"]
    # no bonds (one parameter, or none): rank 1 at every node
    report = dict(cb0.report, node_ranks=np.zeros((cb0.coordinates[0].nodes, 1, 0), dtype=int))
    cb = Codebook(cb0.coordinates, cb0.fields, name="one-parameter", report=report)
    data = P.convergence_data(cb)
    np.testing.assert_array_equal(data["ranks"], np.ones((cb0.coordinates[0].nodes, 1)))
    P.draw_convergence(data)
    # a failed march stores no history: the error says so, with the solver's message
    failed = {"converged": False, "method": "march", "message": "not converged: the solution blows up at t = 0.95",
              "tolerance": 1e-9}
    cb = Codebook(cb0.coordinates, cb0.fields, name="failed", report=failed)
    with pytest.raises(PgdError, match=r"no time-march history .*blows up at t = 0\.95"):
        P.convergence_data(cb)
    bad = dict(cb0.report, node_ranks=np.ones((3, 1, 1), dtype=int))
    with pytest.raises(PgdError, match="node_ranks has shape"):
        P.convergence_data(Codebook(cb0.coordinates, cb0.fields, name="bad", report=bad))


@pytest.mark.parametrize("name", MARCHED)
@pytest.mark.parametrize("kind", ["modes", "convergence"])
def test_render_march_png(march_codebooks, tmp_path, name, kind):
    import warnings

    _, path = march_codebooks[name]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # e.g. constrained layout collapsing: the figure would be unreadable
        out = P.render(path, kind, tmp_path / f"{name}-{kind}.png", dpi=40, size=(5.5, 3.25))
        assert _png_size(out) == (220, 130)
        default = P.render(path, kind, tmp_path / f"{name}-{kind}-default.png")
    data = P.modes_data(Codebook.load(path)) if kind == "modes" else P.convergence_data(Codebook.load(path))
    fig = (P.draw_modes if kind == "modes" else P.draw_convergence)(data)
    fw, fh = fig.get_size_inches() * P.DEFAULT_DPI
    w, h = _png_size(default)
    assert abs(w - fw) <= 1 and abs(h - fh) <= 1


def test_cli_plots_a_tensor_train_codebook(march_codebooks, tmp_path):
    """The reported failures: --kind modes raised AttributeError, --kind convergence found no history."""
    _, path = march_codebooks["coupled"]
    for kind in ("modes", "convergence"):
        out = tmp_path / f"coupled-{kind}.svg"
        r = _run("plot", str(path), "--kind", kind, "-o", str(out))
        assert r.exit_code == 0, r.stderr
        assert r.stdout == f"{out}\n" and r.stderr == ""
        _svg_root(out)
    r = _run("plot", str(path), "--field", "u3", "--count", "3", "-o", str(tmp_path / "u3.png"))
    assert r.exit_code == 0, r.stderr


def test_an_expensive_reference_stops_at_the_time_budget_and_writes_nothing(codebook_path, tmp_path):
    from pgdcli.codebook import io as codebook_io

    cb = Codebook.load(codebook_path("spring"))
    stiff = cb.spec_text.replace('"der(v) = -k*x - c*v"', '"der(v) = -1e8*k*x - c*v"')
    source = tmp_path / "stiff.h5"
    source.write_bytes(codebook_io.to_bytes(Codebook(cb.coordinates, cb.fields, name=cb.name, spec_text=stiff,
                                                     report=cb.report)))
    target = tmp_path / "error.png"
    result = CliRunner().invoke(cli, ["plot", str(source), "--kind", "error", "-o", str(target),
                                      "--max-seconds", "2"])
    assert result.exit_code == 1, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and "time budget of 2 s" in lines[0] and "nothing written" in lines[0], lines
    assert not target.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["stiff.h5"]
