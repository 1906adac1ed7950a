"""pgd export: the C header compiled with the system cc, the JSON layout, the GLSL source."""

from __future__ import annotations

import ctypes
import json
import re
import shutil
import subprocess

import numpy as np
import pytest
from click.testing import CliRunner

from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook, CoordinateInfo, CPTensor, TT
from pgdcli.codebook.export import ExportError, export, layout

CC = shutil.which("cc") or shutil.which("gcc")
GLSLANG = shutil.which("glslangValidator")
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler (cc) on this machine: the C export is not compiled")


def _mixed_codebook():
    """CP and tensor-train unknowns side by side over a slab, a plain Chebyshev and a linear coordinate."""
    coords = [CoordinateInfo("t", (0.0, 2.0), 9, "chebyshev", "time", (0.0, 0.7, 2.0)),
              CoordinateInfo("k", (1.0, 3.0), 6), CoordinateInfo("a", (-1.0, 1.0), 4, "linear")]
    rng = np.random.default_rng(0)
    cp = CPTensor(rng.normal(size=3), tuple(rng.normal(size=(c.nodes, 3)) for c in coords))
    tt = TT((rng.normal(size=(1, 6, 2)), rng.normal(size=(2, 9, 3)), rng.normal(size=(3, 4, 1))), (1, 0, 2))
    return Codebook(coords, {"p": cp, "q": tt}, name="mixed-1")


def _codebooks(solved):
    return {"mixed": _mixed_codebook(), "relaxation": solved("relaxation").codebook,
            "coupled": solved("coupled").codebook}


def _compile(tmp_path, cb):
    files, _ = export(cb, "c")
    ((name, text),) = files.items()
    (tmp_path / name).write_text(text)
    prefix = name[:-2]
    (tmp_path / "drv.c").write_text(f'#include "{name}"\n'
                                    f"int ev(const double *c, double *o) {{ return {prefix}_eval(c, o); }}\n"
                                    f"int evf(const float *c, float *o) {{ return {prefix}_eval_f(c, o); }}\n")
    lib = tmp_path / "drv.so"
    proc = subprocess.run([CC, "-O2", "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-shared", "-fPIC",
                           "-o", str(lib), str(tmp_path / "drv.c")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[:2000]
    return ctypes.CDLL(str(lib))


def _call(lib, cb, points, single=False):
    dtype = np.float32 if single else np.float64
    func = lib.evf if single else lib.ev
    out = np.empty((len(points), len(cb.unknown_names)), dtype=dtype)
    status = np.empty(len(points), dtype=int)
    for i, p in enumerate(np.ascontiguousarray(points, dtype=dtype)):
        status[i] = func(p.ctypes.data_as(ctypes.c_void_p), out[i].ctypes.data_as(ctypes.c_void_p))
    return out.astype(float), status


def _random(cb, n, seed):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(*c.domain, n) for c in cb.coordinates])


def _reference(cb, points):
    values = cb.evaluate(dict(zip(cb.coordinate_names, points.T)))
    return np.column_stack([values[u] for u in cb.unknown_names])


@needs_cc
@pytest.mark.parametrize("name", ["mixed", "relaxation", "coupled"])
def test_c_matches_the_codebook_at_1000_points(solved, tmp_path, name):
    cb = _codebooks(solved)[name]
    lib = _compile(tmp_path, cb)
    points = _random(cb, 1000, seed=1)
    nodes = np.column_stack([c.basis().nodes[np.arange(50) % c.nodes] for c in cb.coordinates])
    points = np.vstack([points, nodes])  # nodes and slab breakpoints: the exact-hit branch
    ref = _reference(cb, points)
    got, status = _call(lib, cb, points)
    assert np.all(status == 0)
    scale = np.maximum(1.0, np.max(np.abs(ref), axis=0))
    assert np.all(np.max(np.abs(got - ref), axis=0) <= 1e-12 * scale), np.max(np.abs(got - ref), axis=0)
    # float32: numbers and arithmetic in single precision, compared at the float32-rounded points,
    # relative to each unknown's largest magnitude
    single = points.astype(np.float32).astype(float)
    got32, status32 = _call(lib, cb, single, single=True)
    ref32 = _reference(cb, single)
    rel = np.max(np.abs(got32 - ref32), axis=0) / np.max(np.abs(ref32), axis=0)
    assert np.all(status32 == 0) and np.all(rel <= 1e-5), rel


@needs_cc
def test_c_clamps_and_reports_out_of_domain_and_nan(tmp_path):
    cb = _mixed_codebook()
    lib = _compile(tmp_path, cb)
    points = np.array([[-0.5, 2.0, 0.3], [1.0, 9.0, -4.0], [float("nan"), 2.0, 0.0]])
    got, status = _call(lib, cb, points)
    assert status.tolist() == [1, 0b110, -1]
    clamped = np.array([[0.0, 2.0, 0.3], [1.0, 3.0, -1.0]])
    assert np.allclose(got[:2], _reference(cb, clamped), rtol=0, atol=1e-12)
    assert np.all(np.isnan(got[2]))


def _json_eval(lay, x):
    """An evaluator of the JSON layout written from its schema (pgdcli.codebook.export's docstring), numpy only."""
    rows = []
    for c, v in zip(lay["coordinates"], x):
        nodes = np.array(c["nodes"])
        if c["kind"] == "linear":
            i = int(np.clip(np.searchsorted(nodes, v, "right") - 1, 0, nodes.size - 2))
            th = (v - nodes[i]) / (nodes[i + 1] - nodes[i])
            w = np.zeros(nodes.size)
            w[i], w[i + 1] = 1 - th, th
        else:
            bp, m = np.array(c["breakpoints"]), c["slab_size"]
            s = int(np.clip(np.searchsorted(bp, v, "right") - 1, 0, bp.size - 2))
            local = nodes[s * (m - 1): s * (m - 1) + m]
            cw = np.where(local == v, 1.0, 0.0) if np.any(local == v) else np.array(c["bary"]) / (v - local)
            w = np.zeros(nodes.size)
            w[s * (m - 1): s * (m - 1) + m] = cw / cw.sum()
        rows.append(w)
    out = []
    for u in lay["unknowns"]:
        if u["representation"] == "cp":
            prod = np.array(u["alphas"])
            for w, modes in zip(rows, u["modes"]):
                prod = prod * (w @ np.array(modes).reshape(w.size, -1))
            out.append(prod.sum())
        else:
            v = np.ones(1)
            for shape, core, j in zip(u["shapes"], u["cores"], u["mode_order"]):
                v = v @ np.einsum("n,anb->ab", rows[j], np.array(core).reshape(shape))
            out.append(v[0])
    return np.array(out)


@pytest.mark.parametrize("name", ["mixed", "relaxation", "coupled"])
def test_json_numbers_evaluate_to_the_codebook(solved, name):
    cb = _codebooks(solved)[name]
    files, size = export(cb, "json")
    lay = json.loads(next(iter(files.values())))
    assert lay["format"] == "pgdcli-export" and lay["version"] == 1
    points = _random(cb, 60, seed=2)
    ref = _reference(cb, points)
    got = np.array([_json_eval(lay, p) for p in points])
    assert np.max(np.abs(got - ref)) <= 1e-12 * max(1.0, np.max(np.abs(ref)))


def test_glsl_numbers_are_the_json_numbers_in_float32_and_it_compiles(solved, tmp_path):
    cb = _mixed_codebook()
    ((_, glsl),) = export(cb, "glsl")[0].items()
    array = re.search(r"const float pgd_mixed_1_data\[(\d+)\] = float\[\d+\]\((.*?)\);", glsl, re.S)
    numbers = np.array([float(v) for v in array.group(2).replace("\n", " ").split(",")])
    flat = []
    lay = layout(cb)
    for c in lay["coordinates"]:
        flat += c["nodes"] + c.get("breakpoints", []) + c.get("bary", [])
    for u in lay["unknowns"]:
        flat += (u["alphas"] + sum(u["modes"], [])) if u["representation"] == "cp" else sum(u["cores"], [])
    assert np.array_equal(numbers, np.array(flat, dtype=np.float32).astype(float))
    if GLSLANG is None:
        pytest.skip("glslangValidator not installed (Debian: glslang-tools): GLSL checked through its numbers only")
    shader = tmp_path / "s.frag"
    shader.write_text("#version 330\n" + glsl + "out vec4 color;\nvoid main() {\n  float c[3] = float[3](0.5, 2.0, 0.1);\n"
                      "  float r[2];\n  int s = pgd_mixed_1_eval(c, r);\n  color = vec4(r[0], r[1], float(s), 1.0);\n}\n")
    proc = subprocess.run([GLSLANG, str(shader)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[:2000]


def test_size_limit_and_force(tmp_path):
    cb = _mixed_codebook()
    with pytest.raises(ExportError, match="over the export limit"):
        export(cb, "c", limit=64)
    assert export(cb, "c", limit=64, force=True)[1] > 64
    path = tmp_path / "m.h5"
    cb.save(path)
    result = CliRunner().invoke(cli, ["export", str(path), "--to", "c", "-o", str(tmp_path / "m.h")], prog_name="pgd")
    assert result.exit_code == 0 and result.stdout == "" and "numbers" in result.stderr
    assert (tmp_path / "m.h").read_text().startswith("/* pgd_mixed_1.h")
    result = CliRunner().invoke(cli, ["export", str(path), "--to", "fortran"], prog_name="pgd")
    assert result.exit_code == 2 and result.stderr.startswith("Error: ")


@needs_cc
def test_the_readme_timing_program_runs_on_the_exported_rigid_body(solved, tmp_path):
    """docs/examples/rigid_body_timing.c (the README's worked example) against Codebook."""
    from conftest import ROOT

    cb = solved("rigid_body").codebook
    ((name, text),) = export(cb, "c")[0].items()
    assert name == "pgd_rigid_body.h"
    (tmp_path / name).write_text(text)
    program = tmp_path / "timing"
    proc = subprocess.run([CC, "-O0", "-std=c99", "-Wall", "-Wextra", "-Werror", "-DPGD_CALLS=50", f"-I{tmp_path}",
                           str(ROOT / "docs" / "examples" / "rigid_body_timing.c"), "-o", str(program)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[:2000]
    out = subprocess.run([str(program)], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[0].startswith("status 0 at t = 0.5") and "us per call" in out[1] and "us per call" in out[2]
    printed = [float(v) for v in re.findall(r"-?\d+\.\d{9}", out[0])]
    values = cb(t=0.5, u10=0.8, u20=1.3, u30=0.6, w10=1.1, w20=0.7, w30=1.4)
    assert np.allclose(printed, [values[u] for u in cb.unknown_names], rtol=0, atol=6e-10)
