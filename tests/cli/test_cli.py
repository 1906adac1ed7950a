"""The ``pgd`` command line (pgdcli.cli.main) through click's CliRunner.

click >= 8.2 keeps stdout and stderr apart in ``Result.stdout`` / ``Result.stderr``.
Expected query output is built from the in-process Codebook and ``repr`` of
floats, the documented format.
"""

from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import PROBLEMS, spec_text

import pgdcli
from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook


@pytest.fixture
def runner():
    return CliRunner()


def _invoke(runner, args, **kwargs):
    # prog_name as the console script sets it (CliRunner would default to the function name)
    return runner.invoke(cli, [str(a) for a in args], prog_name="pgd", **kwargs)


def _assert_usage_error(result, *needles):
    assert result.exit_code == 2, (result.exit_code, result.stdout, result.stderr)
    assert result.stdout == ""
    assert "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and result.stderr.endswith("\n"), result.stderr
    assert lines[0].startswith("Error: "), lines[0]
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def _expected_rows(cb, points, fields=None):
    """What pgd query prints: each point through Codebook.evaluate on its own (one point, one output)."""
    names = list(fields) if fields else cb.unknown_names
    rows = []
    for i in range(len(next(iter(points.values())))):
        values = cb.evaluate({c: float(points[c][i]) for c in cb.coordinate_names}, fields=names)
        rows.append([float(values[u]) for u in names])
    return names, rows


def _product(cb, lists):
    grids = np.meshgrid(*[np.asarray(lists[n], dtype=float) for n in cb.coordinate_names], indexing="ij")
    return {n: g.reshape(-1) for n, g in zip(cb.coordinate_names, grids)}


# ----------------------------------------------------------------------------------------------
# query: exact output
# ----------------------------------------------------------------------------------------------
def test_query_single_point_plain(runner, codebook_path):
    path = codebook_path("parametric")
    cb = Codebook.load(path)
    result = _invoke(runner, ["query", path, "--t", "5", "--k", "2"])
    assert result.exit_code == 0, result.stderr
    assert result.stderr == ""
    expected = repr(float(cb(t=5.0, k=2.0)["u"]))
    assert result.stdout == expected + "\n"
    assert float(result.stdout) == pytest.approx(20.0, abs=1e-12)


def test_query_plain_grid_is_cartesian_first_coordinate_slowest(runner, codebook_path):
    path = codebook_path("spring")
    cb = Codebook.load(path)
    result = _invoke(runner, ["query", path, "--t", "0:4:3", "--k", "1.5,2.5", "--c", "0.3"])
    assert result.exit_code == 0, result.stderr
    points = _product(cb, {"t": [0.0, 2.0, 4.0], "k": [1.5, 2.5], "c": [0.3]})
    np.testing.assert_array_equal(points["t"], [0, 0, 2, 2, 4, 4])
    np.testing.assert_array_equal(points["k"], [1.5, 2.5] * 3)
    _, rows = _expected_rows(cb, points)
    assert result.stdout == "".join(" ".join(repr(v) for v in row) + "\n" for row in rows)


def test_query_csv(runner, codebook_path):
    path = codebook_path("spring")
    cb = Codebook.load(path)
    result = _invoke(runner, ["query", path, "--t", "1,0.5", "--k", "2", "--c", "0.1:0.5:3", "--format", "csv"])
    assert result.exit_code == 0, result.stderr
    points = _product(cb, {"t": [1.0, 0.5], "k": [2.0], "c": np.linspace(0.1, 0.5, 3)})
    names, rows = _expected_rows(cb, points)
    lines = ["t,k,c,x,v"]
    for i, row in enumerate(rows):
        coords = [float(points[n][i]) for n in ("t", "k", "c")]
        lines.append(",".join(repr(v) for v in coords + row))
    assert result.stdout == "\n".join(lines) + "\n"


def test_query_json(runner, codebook_path):
    path = codebook_path("spring")
    cb = Codebook.load(path)
    result = _invoke(runner, ["query", path, "--t", "0,3.5", "--k", "1", "--c", "0.2,0.4", "--format", "json"])
    assert result.exit_code == 0, result.stderr
    assert result.stdout.endswith("\n") and result.stdout.count("\n") == 1
    records = json.loads(result.stdout)
    points = _product(cb, {"t": [0.0, 3.5], "k": [1.0], "c": [0.2, 0.4]})
    names, rows = _expected_rows(cb, points)
    expected = [dict(zip(["t", "k", "c", "x", "v"], [float(points[n][i]) for n in ("t", "k", "c")] + row))
                for i, row in enumerate(rows)]
    assert records == expected  # json round-trips float64 exactly
    assert [list(r) for r in records] == [["t", "k", "c", "x", "v"]] * 4


def test_query_field_selection_and_order(runner, codebook_path):
    path = codebook_path("spring")
    cb = Codebook.load(path)
    args = ["query", path, "--t", "1,2", "--k", "3", "--c", "0.25"]
    points = _product(cb, {"t": [1.0, 2.0], "k": [3.0], "c": [0.25]})
    result = _invoke(runner, args + ["--field", "v"])
    assert result.exit_code == 0, result.stderr
    _, rows = _expected_rows(cb, points, ["v"])
    assert result.stdout == "".join(repr(r[0]) + "\n" for r in rows)
    result = _invoke(runner, args + ["--field", "v", "--field", "x", "--format", "csv"])
    assert result.exit_code == 0, result.stderr
    _, rows = _expected_rows(cb, points, ["v", "x"])
    assert result.stdout.splitlines()[0] == "t,k,c,v,x"
    assert [line.split(",")[3:] for line in result.stdout.splitlines()[1:]] == [[repr(a), repr(b)] for a, b in rows]


def test_query_equals_syntax(runner, codebook_path):
    path = codebook_path("parametric")
    a = _invoke(runner, ["query", path, "--t=5", "--k=2"])
    b = _invoke(runner, ["query", path, "--k", "2", "--t", "5"])
    assert a.exit_code == b.exit_code == 0
    assert a.stdout == b.stdout


def test_query_points_file(runner, codebook_path, tmp_path):
    path = codebook_path("relaxation")
    cb = Codebook.load(path)
    pts = tmp_path / "pts.csv"
    # columns in another order than the codebook's; output rows follow input rows
    pts.write_text("k,u0,t,a\n2,0.5,1,0\n0.5,1,3,-1\n5,0,0,1\n\n")
    result = _invoke(runner, ["query", path, "--points", pts])
    assert result.exit_code == 0, result.stderr
    points = {"t": np.array([1.0, 3.0, 0.0]), "k": np.array([2.0, 0.5, 5.0]), "a": np.array([0.0, -1.0, 1.0]),
              "u0": np.array([0.5, 1.0, 0.0])}
    _, rows = _expected_rows(cb, points)
    assert result.stdout == "".join(repr(r[0]) + "\n" for r in rows)
    result = _invoke(runner, ["query", path, "--points", pts, "--format", "csv"])
    assert result.stdout.splitlines()[0] == "t,k,a,u0,u"
    assert result.stdout.splitlines()[1] == ",".join(repr(v) for v in [1.0, 2.0, 0.0, 0.5, rows[0][0]])


def test_query_points_from_stdin(runner, codebook_path):
    path = codebook_path("parametric")
    cb = Codebook.load(path)
    result = _invoke(runner, ["query", path, "--points", "-", "--format", "json"], input="t,k\n5,2\n10,1\n0,10\n")
    assert result.exit_code == 0, result.stderr
    points = {"t": np.array([5.0, 10.0, 0.0]), "k": np.array([2.0, 1.0, 10.0])}
    _, rows = _expected_rows(cb, points)
    assert json.loads(result.stdout) == [{"t": t, "k": k, "u": r[0]} for t, k, r in zip([5.0, 10.0, 0.0],
                                                                                     [2.0, 1.0, 10.0], rows)]


def test_query_domain_ends_accepted(runner, codebook_path):
    result = _invoke(runner, ["query", codebook_path("parametric"), "--t", "0,10", "--k", "1,10"])
    assert result.exit_code == 0, result.stderr
    assert len(result.stdout.splitlines()) == 4


# ----------------------------------------------------------------------------------------------
# query: error paths (exit 2, one "Error:" line, no traceback)
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "args,needles",
    [
        (["--t", "1"], ["missing", "k", "[1, 10]"]),
        ([], ["missing", "t", "k"]),
        (["--t", "1", "--k", "2", "--q", "3"], ["unknown coordinate", "q"]),
        (["--t", "11", "--k", "2"], ["t", "11", "[0, 10]"]),
        (["--t", "1", "--k", "0.5"], ["k", "0.5", "[1, 10]"]),
        (["--t", "1,2,-3", "--k", "2"], ["t", "-3", "[0, 10]"]),
        (["--t", "0:12:4", "--k", "2"], ["t", "12", "[0, 10]"]),
        (["--t", "nan", "--k", "2"], ["--t", "nan", "not a finite number"]),
        (["--t", "abc", "--k", "2"], ["--t", "abc"]),
        (["--t", "1:2", "--k", "2"], ["--t", "1:2"]),
        (["--t", "1:2:0", "--k", "2"], ["--t"]),
        (["--t", "1,,2", "--k", "2"], ["--t"]),
        (["--t", "", "--k", "2"], ["--t"]),
        (["--t", "1", "--k", "2", "--field", "w"], ["field", "w"]),
        (["--t", "1", "--k", "2", "--t", "3"], ["--t", "twice"]),
        (["--t", "1", "--k", "2", "--format", "xml"], ["xml"]),
        (["--t", "1", "--k"], ["k"]),
        (["--t", "1", "--k", "2", "stray"], ["stray"]),
    ],
)
def test_query_usage_errors(runner, codebook_path, args, needles):
    result = _invoke(runner, ["query", codebook_path("parametric")] + args)
    _assert_usage_error(result, *needles)


@pytest.mark.parametrize(
    "text,needles",
    [
        ("t,z\n1,2\n", ["unknown column", "z"]),
        ("t,k\n1,x\n", ["not a number", "line 2"]),
        ("t\n1\n", ["missing", "k"]),
        ("t,k\n1,2,3\n", ["line 2"]),
        ("t,k\n1,20\n", ["k", "20", "[1, 10]"]),
        ("", ["empty"]),
    ],
)
def test_query_points_errors(runner, codebook_path, tmp_path, text, needles):
    pts = tmp_path / "p.csv"
    pts.write_text(text)
    _assert_usage_error(_invoke(runner, ["query", codebook_path("parametric"), "--points", pts]), *needles)
    # the same from stdin
    _assert_usage_error(_invoke(runner, ["query", codebook_path("parametric"), "--points", "-"], input=text),
                        *needles)


def test_query_points_mixed_with_coordinates(runner, codebook_path, tmp_path):
    pts = tmp_path / "p.csv"
    pts.write_text("t,k\n1,2\n")
    _assert_usage_error(_invoke(runner, ["query", codebook_path("parametric"), "--points", pts, "--t", "1"]),
                        "--points")


def test_query_points_file_missing(runner, codebook_path, tmp_path):
    _assert_usage_error(_invoke(runner, ["query", codebook_path("parametric"), "--points", tmp_path / "no.csv"]),
                        "no.csv")


def test_query_missing_codebook(runner, tmp_path):
    missing = tmp_path / "missing.h5"
    _assert_usage_error(_invoke(runner, ["query", missing, "--t", "1"]), str(missing))


def test_query_non_codebook_file(runner):
    spec = PROBLEMS / "spring.yaml"
    _assert_usage_error(_invoke(runner, ["query", spec, "--t", "1"]), str(spec))


def test_query_truncated_codebook(runner, codebook_path, tmp_path):
    cut = tmp_path / "cut.h5"
    cut.write_bytes(codebook_path("parametric").read_bytes()[:1000])
    _assert_usage_error(_invoke(runner, ["query", cut, "--t", "1", "--k", "2"]), str(cut))


def test_info_missing_codebook(runner, tmp_path):
    _assert_usage_error(_invoke(runner, ["info", tmp_path / "nope.h5"]), "nope.h5")


# ----------------------------------------------------------------------------------------------
# solve
# ----------------------------------------------------------------------------------------------
def test_solve_writes_codebook(runner, tmp_path):
    out = tmp_path / "sub" / "parametric.h5"
    result = _invoke(runner, ["solve", PROBLEMS / "parametric.yaml", "-o", out])
    assert result.exit_code == 0, result.stderr
    assert result.stdout == ""
    assert "Traceback" not in result.stderr
    cb = Codebook.load(out)
    t, k = np.meshgrid(np.linspace(0, 10, 23), np.linspace(1, 10, 29), indexing="ij")
    np.testing.assert_allclose(cb(t=t, k=k)["u"], (10 / k - 1) * t, rtol=0, atol=1e-10)
    assert cb.report["converged"]
    assert sorted(p.name for p in out.parent.iterdir()) == ["parametric.h5"]  # no temporary files left


def test_solve_json_summary(runner, tmp_path):
    out = tmp_path / "p.h5"
    result = _invoke(runner, ["solve", PROBLEMS / "parametric.yaml", "-o", out, "--format", "json", "-q"])
    assert result.exit_code == 0, result.stderr
    summary = json.loads(result.stdout)
    for key in ("problem", "converged", "residual", "tolerance", "modes", "coordinates", "wall_time", "output"):
        assert key in summary, key
    assert summary["problem"] == "parametric"
    assert summary["converged"] is True
    assert summary["residual"] <= summary["tolerance"] == 1e-12
    assert summary["modes"] == {"u": Codebook.load(out).fields["u"].rank}
    assert summary["coordinates"] == {"t": 8, "k": 56}
    assert summary["output"] == str(out)
    assert result.stderr == ""  # -q: nothing on stderr


def _enrichment_only(tmp_path):
    """spring.yaml solved by the enrichment alone (auto falls back to the tensor-train solver at max_modes)."""
    spec = tmp_path / "spring.yaml"
    spec.write_text((PROBLEMS / "spring.yaml").read_text().replace("  tolerance: 1e-10", "  tolerance: 1e-10\n  method: pgd"))
    return spec


def test_solve_not_converged_exits_1_without_file(runner, tmp_path):
    spec = _enrichment_only(tmp_path)
    out = tmp_path / "spring.h5"
    result = _invoke(runner, ["solve", spec, "-o", out, "--max-modes", "1"])
    assert result.exit_code == 1, (result.stdout, result.stderr)
    assert result.stdout == ""
    assert not out.exists()
    assert list(tmp_path.iterdir()) == [spec]
    assert "Traceback" not in result.stderr
    last = result.stderr.splitlines()[-1]
    assert last.startswith("Error: ") and "not converged" in last
    assert "residual" in last


def test_solve_not_converged_json(runner, tmp_path):
    out = tmp_path / "spring.h5"
    result = _invoke(runner, ["solve", _enrichment_only(tmp_path), "-o", out, "--max-modes", "1", "--format", "json",
                              "-q"])
    assert result.exit_code == 1
    summary = json.loads(result.stdout)
    assert summary["converged"] is False and summary["output"] is None
    assert summary["residual"] > summary["tolerance"]
    assert not out.exists()


def test_solve_default_output_path(runner, tmp_path, monkeypatch):
    (tmp_path / "p.yaml").write_text((PROBLEMS / "parametric.yaml").read_text())
    monkeypatch.chdir(tmp_path)
    result = _invoke(runner, ["solve", "p.yaml", "-q"])
    assert result.exit_code == 0, result.stderr
    assert (tmp_path / "codebooks" / "parametric.h5").is_file()  # the spec's name, not the file stem


def test_solve_unwritable_output_is_a_one_line_error(runner, tmp_path):
    blocker = tmp_path / "afile"
    blocker.write_text("not a directory")
    target = blocker / "out.h5"
    result = _invoke(runner, ["solve", PROBLEMS / "parametric.yaml", "-o", target, "-q"])
    _assert_usage_error(result, str(target.parent))
    assert blocker.read_text() == "not a directory"


def test_solve_bad_yaml(runner, tmp_path):
    spec = tmp_path / "bad.yaml"
    spec.write_text("coordinates: [\n")
    _assert_usage_error(_invoke(runner, ["solve", spec, "-o", tmp_path / "x.h5"]), str(spec))
    assert not (tmp_path / "x.h5").exists()


def test_solve_unknown_key(runner, tmp_path):
    spec = tmp_path / "unknown.yaml"
    spec.write_text(textwrap.dedent(
        spec_text(
            bogus=' 1',
        )
    ))
    _assert_usage_error(_invoke(runner, ["solve", spec, "-o", tmp_path / "x.h5"]), str(spec), "bogus")
    assert not (tmp_path / "x.h5").exists()


def test_solve_missing_spec(runner, tmp_path):
    _assert_usage_error(_invoke(runner, ["solve", tmp_path / "none.yaml"]), "none.yaml")


@pytest.mark.parametrize("args,needle", [(["--tolerance", "2"], "--tolerance"), (["--max-modes", "0"], "--max-modes"),
                                         (["--max-modes", "many"], "--max-modes")])
def test_solve_bad_options(runner, tmp_path, args, needle):
    out = tmp_path / "p.h5"
    _assert_usage_error(_invoke(runner, ["solve", PROBLEMS / "parametric.yaml", "-o", out] + args), needle)
    assert not out.exists()


# ----------------------------------------------------------------------------------------------
# info, help, version
# ----------------------------------------------------------------------------------------------
def test_info_text_and_json(runner, codebook_path):
    path = codebook_path("spring")
    result = _invoke(runner, ["info", path])
    assert result.exit_code == 0, result.stderr
    for word in ("spring", "t", "k", "c", "[1, 4]", "residual"):
        assert word in result.stdout
    result = _invoke(runner, ["info", path, "--format", "json"])
    assert result.exit_code == 0
    info = json.loads(result.stdout)
    assert [c["name"] for c in info["coordinates"]] == ["t", "k", "c"]
    cb = Codebook.load(path)
    assert info["unknowns"] == {
        u: {"representation": "cp", "modes": fm.rank, "floats": fm.weights.size + sum(m.size for m in fm.factors)}
        for u, fm in cb.fields.items()
    }
    assert info["size_bytes"] == path.stat().st_size


def test_info_spec_prints_the_stored_spec_that_solves_again(runner, codebook_path, tmp_path):
    path = codebook_path("parametric")
    result = _invoke(runner, ["info", path, "--spec"])
    assert result.exit_code == 0, result.stderr
    assert result.stdout == (PROBLEMS / "parametric.yaml").read_text() and result.stderr == ""
    spec = tmp_path / "again.yaml"
    spec.write_text(result.stdout)
    again = pgdcli.solve(pgdcli.load_spec(spec))
    before = Codebook.load(path)
    t, k = np.linspace(0, 10, 7), np.linspace(1, 10, 5)
    assert np.array_equal(again.codebook(t=t[:, None], k=k)["u"], before(t=t[:, None], k=k)["u"])


def test_info_spec_of_a_codebook_without_spec_is_one_error_line(runner, codebook_path, tmp_path):
    cb = Codebook.load(codebook_path("parametric"))
    cb.spec_text = ""
    path = cb.save(tmp_path / "nospec.h5")
    _assert_usage_error(_invoke(runner, ["info", path, "--spec"]), "nospec.h5", "holds no problem spec")


def test_version(runner):
    for flag in ("--version", "-V"):
        result = _invoke(runner, [flag])
        assert result.exit_code == 0
        assert result.stdout == f"pgd {pgdcli.__version__}\n"


@pytest.mark.parametrize("args", [["--help"], ["-h"], ["query", "--help"], ["solve", "--help"], ["info", "--help"]])
def test_help(runner, args):
    result = _invoke(runner, args)
    assert result.exit_code == 0, result.stderr
    assert result.stdout.startswith("Usage: pgd")
    assert result.stderr == ""


def test_console_script_help_and_version():
    import shutil
    import subprocess

    exe = shutil.which("pgd")
    if exe is None:
        pytest.skip("pgd console script not on PATH")
    out = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.startswith("Usage: pgd") and out.stderr == ""
    out = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout == f"pgd {pgdcli.__version__}\n"


def test_help_content(runner):
    top = _invoke(runner, ["--help"]).stdout
    for cmd in ("solve", "query", "info"):
        assert cmd in top
    q = _invoke(runner, ["query", "--help"]).stdout
    for opt in ("--format", "--field", "--points", "start:stop:count"):
        assert opt in q
    s = _invoke(runner, ["solve", "--help"]).stdout
    for opt in ("--output", "--tolerance", "--max-modes", "--format"):
        assert opt in s


def test_points_file_with_a_repeated_column_is_an_error(tmp_path):
    from pgdcli.cli.main import cli

    cb_path = tmp_path / "p.h5"
    import pgdcli

    pgdcli.solve(pgdcli.load_spec("problems/parametric.yaml")).codebook.save(cb_path)
    points = tmp_path / "pts.csv"
    points.write_text("t,k,k\n1,2,3\n")
    result = CliRunner().invoke(cli, ["query", str(cb_path), "--points", str(points)], prog_name="pgd")
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error:") and "'k'" not in lines[0] and "k appear" in lines[0]
