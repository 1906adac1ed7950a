"""A quick end-to-end pass over every command on one small problem with an exact solution.

``pytest -m smoke`` runs only these (seconds); the full suite runs them too. The problem is a
forced relaxation ``u' = -k u + a``, ``u(0) = u0``, exact ``u = a/k + (u0 - a/k) exp(-k t)``.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from pgdcli.cli.main import cli

pytestmark = pytest.mark.smoke

SPEC = """\
name: decay
coordinates:
  t: {domain: [0, 2]}
  k: {domain: [0.5, 3]}
  a: {domain: [0, 1], nodes: 2, discretization: linear}
unknowns:
  u: {initial: 1}
equations:
  - "der(u) = -k*u + a"
solver:
  tolerance: 1e-8
"""


def exact(t, k, a, u0=1.0):
    return a / k + (u0 - a / k) * np.exp(-k * t)


def pgd(*args, stdin=None):
    return CliRunner().invoke(cli, [str(a) for a in args], prog_name="pgd", input=stdin)


@pytest.fixture(scope="module")
def codebook(tmp_path_factory):
    folder = tmp_path_factory.mktemp("smoke")
    spec = folder / "decay.yaml"
    spec.write_text(SPEC)
    result = pgd("solve", spec, "-o", folder / "decay.h5", "-q", "--format", "json")
    assert result.exit_code == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["accurate"] is True and report["check_error"] <= 1e-8
    return folder / "decay.h5"


def test_query_matches_the_exact_solution(codebook):
    rng = np.random.default_rng(0)
    t, k, a = rng.uniform(0, 2, 20), rng.uniform(0.5, 3, 20), rng.uniform(0, 1, 20)
    points = "t,k,a\n" + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in zip(t.tolist(), k.tolist(), a.tolist()))
    result = pgd("query", codebook, "--points", "-", stdin=points)
    assert result.exit_code == 0, result.stderr
    values = np.array([float(line) for line in result.stdout.split()])
    assert np.max(np.abs(values - exact(t, k, a))) <= 1e-8


def test_info_and_the_stored_spec(codebook):
    info = json.loads(pgd("info", codebook, "--format", "json").stdout)
    assert [c["name"] for c in info["coordinates"]] == ["t", "k", "a"] and info["accurate"] is True
    assert pgd("info", codebook, "--spec").stdout == SPEC


def test_verify_passes_its_own_tolerance(codebook):
    result = pgd("verify", codebook, "--samples", 8, "--times", 4, "-j", 1, "-q", "--format", "json")
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["gate"]["tolerance"] == 1e-8


def test_fit_recovers_the_rate(codebook):
    t = np.linspace(0, 2, 25)
    u = exact(t, 1.7, 0.4) + np.random.default_rng(1).normal(0, 1e-3, t.size)
    data = "t,u\n" + "".join(f"{x!r},{y!r}\n" for x, y in zip(t.tolist(), u.tolist()))
    result = pgd("fit", codebook, "-", "--fix", "a=0.4", "--sigma", "u=1e-3", "--format", "json", "-q", stdin=data)
    assert result.exit_code == 0, result.stderr
    fit = json.loads(result.stdout)
    assert abs(fit["estimate"]["k"] - 1.7) <= 3 * fit["stderr"]["k"] and fit["success"] is True


def test_export_json_and_c(codebook, tmp_path):
    exported = json.loads(pgd("export", codebook, "--to", "json", "-q").stdout)
    assert [c["name"] for c in exported["coordinates"]] == ["t", "k", "a"]
    header = tmp_path / "pgd_decay.h"
    assert pgd("export", codebook, "--to", "c", "-o", header, "-q").exit_code == 0
    if shutil.which("cc") is None:
        pytest.skip("no C compiler")
    import subprocess

    program = tmp_path / "decay.c"
    program.write_text('#include <stdio.h>\n#include "pgd_decay.h"\nint main(void) {\n'
                       '    double x[3] = {1.25, 2.0, 0.3}, u[1];\n    int status = pgd_decay_eval(x, u);\n'
                       '    printf("%d %.17g\\n", status, u[0]);\n    return 0;\n}\n')
    subprocess.run(["cc", "-std=c99", "-O2", f"-I{tmp_path}", str(program), "-o", str(tmp_path / "decay")],
                   check=True, capture_output=True)
    status, value = subprocess.run([str(tmp_path / "decay")], capture_output=True, text=True, check=True).stdout.split()
    assert status == "0" and abs(float(value) - exact(1.25, 2.0, 0.3)) <= 1e-8
