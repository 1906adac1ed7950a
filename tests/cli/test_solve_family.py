"""``pgd solve`` of several specs or a folder (pgdcli.cli.solve_family, pgdcli.family): every valid spec
built and written, an invalid one reported in its row without stopping the others, collisions refused
before any work. The same family on a real cluster: tests/test_cluster.py.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
from click.testing import CliRunner
from conftest import EXACT, PROBLEMS, codebook_points, max_abs_error

from pgdcli import Codebook
from pgdcli.cli.main import cli


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def family_folder(tmp_path):
    folder = tmp_path / "specs"
    folder.mkdir()
    for name in ("parametric", "relaxation"):
        shutil.copy(PROBLEMS / f"{name}.yaml", folder / f"{name}.yaml")
    (folder / "broken.yaml").write_text("name: broken\ncoordinates: {t: {domain: [0, 1]}}\n")
    (folder / "notes.txt").write_text("not a spec")
    return folder


def test_a_folder_builds_every_valid_spec_and_reports_the_invalid_one(tmp_path):
    out = tmp_path / "books"
    result = run("solve", family_folder(tmp_path), "-o", out, "--format", "json")
    assert result.exit_code == 2
    rows = json.loads(result.stdout)
    assert [r["spec"].rsplit("/", 1)[-1] for r in rows] == ["broken.yaml", "parametric.yaml", "relaxation.yaml"]
    assert rows[0]["status"] == "invalid" and "unknowns" in rows[0]["error"]
    assert [r["status"] for r in rows[1:]] == ["written", "written"]
    assert result.stderr.strip().splitlines()[-1] == (
        f"Error: 1 of 3 specs without a codebook: {rows[0]['spec']} (invalid)")
    for name in ("parametric", "relaxation"):  # each codebook within its tolerance of the exact solution
        cb = Codebook.load(out / f"{name}.h5")
        errors = max_abs_error(cb, EXACT[name], codebook_points(cb, 200, seed=3))
        assert max(errors.values()) <= cb.report["tolerance"]
    assert "pgd solve: 3 specs" in result.stderr


def test_a_family_that_builds_is_exit_0_with_one_row_each(tmp_path):
    out = tmp_path / "books"
    result = run("solve", PROBLEMS / "parametric.yaml", PROBLEMS / "relaxation.yaml", "-o", out, "-q")
    assert result.exit_code == 0, result.output
    assert result.stdout == "" and result.stderr == ""
    assert sorted(p.name for p in out.iterdir()) == ["parametric.h5", "relaxation.h5"]


def test_the_family_codebook_is_the_single_build(tmp_path):
    run("solve", PROBLEMS / "parametric.yaml", "-o", tmp_path / "one.h5", "-q")
    run("solve", PROBLEMS / "parametric.yaml", PROBLEMS / "relaxation.yaml", "-o", tmp_path / "books", "-q")
    a, b = Codebook.load(tmp_path / "one.h5"), Codebook.load(tmp_path / "books" / "parametric.h5")
    points = codebook_points(a, 50, seed=1)
    assert all(np.array_equal(a(**points)[u], b(**points)[u]) for u in a.unknown_names)


def test_two_specs_writing_one_file_are_refused_before_any_work(tmp_path):
    twin = tmp_path / "twin.yaml"
    twin.write_text((PROBLEMS / "parametric.yaml").read_text() + f"\noutput: {tmp_path / 'same.h5'}\n")
    other = tmp_path / "other.yaml"
    other.write_text(twin.read_text())
    result = run("solve", twin, other)
    assert result.exit_code == 2
    assert "would both write" in result.stderr and not (tmp_path / "same.h5").exists()


def test_family_usage_errors(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    for args, fragment in (([empty], "no spec"),
                           ([PROBLEMS / "parametric.yaml", PROBLEMS / "parametric.yaml"], "given twice"),
                           ([PROBLEMS / "parametric.yaml", PROBLEMS / "relaxation.yaml", "-o", tmp_path / "x.h5"],
                            "names the folder"),
                           ([PROBLEMS / "parametric.yaml", PROBLEMS / "relaxation.yaml", "--tolerance", "2"],
                            "--tolerance")):
        result = run("solve", *args)
        assert result.exit_code == 2, result.output
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and fragment in lines[0], result.stderr
