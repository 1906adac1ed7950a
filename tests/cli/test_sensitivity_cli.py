"""``pgd sensitivity``: the three formats carry the library's numbers; bad input is one line, exit 2."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest
from click.testing import CliRunner

from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook


def _run(*args):
    return CliRunner().invoke(cli, ["sensitivity", *map(str, args)], catch_exceptions=False)


def test_formats_carry_the_library_numbers(codebook_path):
    path = codebook_path("spring")
    expected = Codebook.load(path).sensitivity(times=[1.0, 2.0, 4.0], densities={"k": "normal:2,0.5"},
                                               second_order=True)
    r = _run(path, "--times", "1,2,4", "--density", "k=normal:2,0.5", "--second-order", "--format", "csv")
    assert r.exit_code == 0, r.stderr
    rows = list(csv.DictReader(io.StringIO(r.stdout)))
    assert list(rows[0]) == ["unknown", "t", "mean", "variance", "first_k", "first_c", "total_k", "total_c",
                             "second_k_c"]
    assert len(rows) == 6 and rows[4]["unknown"] == "v" and float(rows[4]["t"]) == 2.0
    assert float(rows[4]["first_c"]) == expected.first["v"][1, 1]  # full precision
    assert float(rows[5]["second_k_c"]) == expected.second["v"][2, 0, 1]
    assert r.stderr.startswith("sensitivity: 2 unknown(s), 2 input(s) (k, c) at 3 times")
    r = _run(path, "--times", "0:4:3", "--format", "json", "-q")
    data = json.loads(r.stdout)
    assert r.stderr == "" and data["times"] == [0.0, 2.0, 4.0] and data["inputs"] == ["k", "c"]
    assert data["unknowns"]["v"]["first"]["k"][0] is None  # v(0) = 0 for every k, c: no variance, no index
    plain = _run(path, "--times", "2", "--field", "x", "-q").stdout.splitlines()
    assert plain[0].split() == ["unknown", "t", "mean", "variance", "first_k", "first_c", "total_k", "total_c"]
    values = plain[1].split()
    uniform = Codebook.load(path).sensitivity(times=[2.0], fields=["x"])
    assert values[0] == "x" and float(values[4]) == pytest.approx(uniform.first["x"][0, 0], rel=1e-5)  # 6 digits


def test_fixed_coordinates_and_steady_codebooks(codebook_path, solved):
    path = codebook_path("spring")
    r = _run(path, "--at", "c=0.3", "--times", "3", "--format", "json", "-q")
    data = json.loads(r.stdout)
    assert data["inputs"] == ["k"] and data["at"] == {"c": 0.3}
    assert data["unknowns"]["x"]["first"]["k"] == [pytest.approx(1.0, abs=1e-12)]


@pytest.mark.parametrize("args, message", [
    (["--times", "9"], "--times: 9.0 is outside the domain [0, 4] of 't'"),
    (["--times", "a,b"], "'a,b' is not a number, a comma list or start:stop:count"),
    (["--at", "k=7"], "--at k=7: outside the domain [1, 4] of 'k'"),
    (["--at", "t=1"], "'t' is the time coordinate; give its values with --times"),
    (["--at", "k=2", "--at", "k=3"], "--at: coordinate 'k' given twice"),
    (["--density", "k"], "expected NAME=SPEC"),
    (["--density", "q=uniform"], "unknown coordinate 'q'"),
    (["--density", "k=normal:2"], "--density k=normal:2: expected uniform, uniform:LOW,HIGH or normal:MEAN,SD"),
    (["--density", "k=uniform:0,2"], "--density k=uniform:0.0,2.0: [0, 2] is not an interval inside the domain [1, 4]"),
    (["--field", "w"], "unknown 'w'; this codebook has x, v"),
    (["--format", "xml"], "Invalid value for '--format'"),
])
def test_errors_are_one_line_exit_2(codebook_path, args, message):
    r = _run(codebook_path("spring"), *args)
    assert r.exit_code == 2 and r.stdout == ""
    assert len(r.stderr.splitlines()) == 1 and r.stderr.startswith("Error: ") and message in r.stderr, r.stderr


def test_space_coordinates_must_be_held(tmp_path):
    from pgdcli.codebook.codebook import CoordinateInfo, CPTensor

    rng = np.random.default_rng(0)
    coords = [CoordinateInfo("t", (0.0, 1.0), 4, "chebyshev", "time"), CoordinateInfo("x", (0.0, 1.0), 4, "chebyshev",
                                                                                     "space"),
              CoordinateInfo("k", (1.0, 2.0), 3)]
    path = Codebook(coords, {"u": CPTensor(np.ones(1), tuple(rng.standard_normal((4 if c.name != "k" else 3, 1))
                                                               for c in coords))}, report={}).save(tmp_path / "s.h5")
    r = _run(path)
    assert r.exit_code == 2 and "give a value for the space coordinate x (e.g. --at x=...)" in r.stderr
    r = _run(path, "--at", "x=0.5", "--times", "0.5", "--format", "json", "-q")
    assert r.exit_code == 0 and json.loads(r.stdout)["inputs"] == ["k"]
