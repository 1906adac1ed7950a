"""--scheduler / --workers / PGD_SCHEDULER on the command line (pgdcli.cli.cluster_options): refused
combinations are one usage line, and nothing imports Dask unless a cluster is asked for. The work on
a real cluster is tested in tests/test_cluster.py.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
from click.testing import CliRunner
from conftest import PROBLEMS

from pgdcli.cli.main import cli


def run(*args, env=None):
    return CliRunner().invoke(cli, list(args), env=env)


def one_error(result, *fragments) -> None:
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.stderr
    for fragment in fragments:
        assert fragment in lines[0]


def test_scheduler_and_workers_together_are_refused(tmp_path):
    one_error(run("solve", str(PROBLEMS / "parametric.yaml"), "-o", str(tmp_path / "p.h5"), "--scheduler",
                  "tcp://127.0.0.1:8786", "--workers", "2"), "not both")


def test_jobs_with_a_cluster_is_refused(tmp_path):
    one_error(run("verify", str(tmp_path / "x.h5"), "--jobs", "2", "--workers", "2"), "--jobs runs local processes")


def test_a_cluster_for_a_query_to_stdout_is_refused(parametric_codebook):
    one_error(run("query", str(parametric_codebook), "--t", "1", "--k", "2", "--workers", "2"), "add --output")


def test_pgd_scheduler_does_not_touch_a_query_to_stdout(parametric_codebook):
    result = run("query", str(parametric_codebook), "--t", "1", "--k", "2", env={"PGD_SCHEDULER": "tcp://127.0.0.1:9"})
    assert result.exit_code == 0 and result.stdout.strip()


def test_an_empty_pgd_scheduler_is_no_cluster(tmp_path):
    result = run("solve", str(PROBLEMS / "parametric.yaml"), "-o", str(tmp_path / "p.h5"), "-q",
                 env={"PGD_SCHEDULER": " "})
    assert result.exit_code == 0, result.output
    assert (tmp_path / "p.h5").exists()


def test_workers_must_be_a_positive_count(tmp_path):
    one_error(run("solve", str(PROBLEMS / "parametric.yaml"), "--workers", "0"), "--workers")


@pytest.fixture
def parametric_codebook(tmp_path):
    path = tmp_path / "parametric.h5"
    assert run("solve", str(PROBLEMS / "parametric.yaml"), "-o", str(path), "-q").exit_code == 0
    return path


@pytest.mark.parametrize("argv", [["--help"], ["solve", "--help"], ["verify", "--help"], ["query", "CODEBOOK"]])
def test_no_dask_import_without_a_cluster(argv, parametric_codebook):
    argv = [str(parametric_codebook) if a == "CODEBOOK" else a for a in argv]
    if argv[0] == "query":
        argv += ["--t", "1", "--k", "2"]
    code = ("import sys; from pgdcli.cli.entry import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed'))\n"
            "sys.stderr.write('DASK:' + ','.join(bad))")
    done = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=120)
    assert done.stderr.strip().endswith("DASK:"), done.stderr[-500:]
