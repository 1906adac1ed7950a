"""``pgd query ... --output FILE.h5`` (pgdcli.cli.query_output): points from a CSV file, an HDF5 file or
the --NAME grid, evaluated in partitions into an HDF5 file; bad points are one error line naming the
file, the row and the coordinate, and leave no file. On a cluster: tests/test_cluster.py.
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import PROBLEMS

from pgdcli import Codebook
from pgdcli.cli.main import cli


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def spring(tmp_path_factory):
    path = tmp_path_factory.mktemp("books") / "spring.h5"
    assert run("solve", PROBLEMS / "spring.yaml", "-o", path, "-q").exit_code == 0
    return path


def columns(path) -> dict:
    with h5py.File(path) as f:
        return {f"{g}/{n}": f[g][n][()] for g in ("coordinates", "values") for n in f[g]}


def test_csv_hdf5_and_grid_points_give_one_file(spring, tmp_path):
    cb = Codebook.load(spring)
    t, k = np.linspace(0, 4, 9), np.array([1.5, 3.0])
    tt, kk = (a.reshape(-1).tolist() for a in np.meshgrid(t, k, indexing="ij"))
    (tmp_path / "p.csv").write_text("k,c,t\n" + "".join(f"{b!r},0.3,{a!r}\n" for a, b in zip(tt, kk)))
    with h5py.File(tmp_path / "p.h5", "w") as f:
        f["coordinates/t"], f["coordinates/k"], f["coordinates/c"] = tt, kk, np.full(len(tt), 0.3)
    made = [run("query", spring, "--points", tmp_path / "p.csv", "--output", tmp_path / "a.h5"),
            run("query", spring, "--points", tmp_path / "p.h5", "--output", tmp_path / "b.h5"),
            run("query", spring, "--t", "0:4:9", "--k", "1.5,3", "--c", "0.3", "--output", tmp_path / "c.h5")]
    assert all(r.exit_code == 0 and r.stdout == "" for r in made), [r.output for r in made]
    assert "wrote 18 points" in made[0].stderr
    a, b, c = (columns(tmp_path / f"{n}.h5") for n in "abc")
    assert all(np.array_equal(a[key], b[key]) and np.array_equal(a[key], c[key]) for key in a)
    assert np.array_equal(a["coordinates/t"], tt)
    np.testing.assert_allclose(a["values/x"], cb.evaluate({"t": tt, "k": kk, "c": 0.3})["x"], rtol=0, atol=1e-15)


def test_bad_points_are_one_error_line_and_no_file(spring, tmp_path):
    out = tmp_path / "v.h5"
    with h5py.File(tmp_path / "short.h5", "w") as f:
        f["t"], f["k"], f["c"] = np.ones(3), np.ones(2), np.ones(3)
    with h5py.File(tmp_path / "outside.h5", "w") as f:
        f["t"], f["k"], f["c"] = np.array([1.0, 5.0]), np.full(2, 2.0), np.full(2, 0.3)
    with h5py.File(tmp_path / "missing.h5", "w") as f:
        f["t"], f["k"] = np.ones(3), np.ones(3)
    (tmp_path / "bad.csv").write_text("t,k,c\n1,2,0.3\n1,x,0.3\n")
    cases = [(tmp_path / "short.h5", "differ in length"), (tmp_path / "outside.h5", "row 2: coordinate 't'"),
             (tmp_path / "missing.h5", "'c'"), (tmp_path / "bad.csv", "line 3"), (tmp_path / "nope.h5", "no such file")]
    for points, fragment in cases:
        result = run("query", spring, "--points", points, "--output", out)
        assert result.exit_code == 2, result.output
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("Error: ") and fragment in lines[0], result.stderr
        assert not out.exists() and [p.name for p in tmp_path.glob(".v.h5*")] == []


def test_the_output_must_be_an_hdf5_file(spring, tmp_path):
    result = run("query", spring, "--t", "1", "--k", "2", "--c", "0.3", "--output", tmp_path / "v.csv")
    assert result.exit_code == 2 and "unsupported file type" in result.stderr


@pytest.mark.parametrize("fmt", ["csv", "json"])
def test_a_format_with_an_output_file_is_refused(spring, tmp_path, fmt):
    out = tmp_path / "v.h5"
    result = run("query", spring, "--t", "1", "--k", "2", "--c", "0.3", "--format", fmt, "--output", out)
    lines = result.stderr.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1 and "--format" in lines[0] and "--output" in lines[0], result.stderr
    assert not out.exists()
