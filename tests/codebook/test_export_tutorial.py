"""The engine tutorial end to end: docs/examples/projectile.yaml solved, exported to C, and
docs/examples/projectile_loop.c compiled with the system cc, its printed values held to Codebook."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import pgdcli
from pgdcli.codebook.export import export

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "docs" / "examples"


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")
def test_projectile_loop_prints_the_codebooks_values(tmp_path):
    result = pgdcli.solve(pgdcli.load_spec(EXAMPLES / "projectile.yaml"))
    assert result.converged and result.accurate, result.message
    cb = result.codebook
    files, _ = export(cb, "c")
    ((name, text),) = files.items()
    (tmp_path / name).write_text(text)
    program = tmp_path / "projectile_loop"
    subprocess.run(["cc", "-O2", "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", f"-I{tmp_path}",
                    str(EXAMPLES / "projectile_loop.c"), "-o", str(program)], check=True, capture_output=True)
    out = subprocess.run([str(program)], check=True, capture_output=True, text=True, timeout=120).stdout
    shots = re.findall(r"shot \d+ \(v0 (\S+), a (\S+), k (\S+)\) at t = 1.5: x = (\S+), y = (\S+) \(status 0\)", out)
    assert len(shots) == 2, out
    for v0, a, k, x, y in shots:
        want = cb.evaluate({"t": 1.5, "v0": float(v0), "a": float(a), "k": float(k)})
        for got, u in ((float(x), "x"), (float(y), "y")):
            assert abs(got - float(want[u])) <= 1e-12 * max(1.0, abs(float(want[u]))), (u, got, want[u])
    # a landing time is the first frame (1/60 s apart) below the ground, by the codebook as well
    for shot, landed in re.findall(r"shot (\d+) lands at t = (\S+) s", out):
        i = int(shot)
        v0, a, k = 10.0 + 20.0 * i / 63, 0.1 + 1.4 * ((i * 37) % 64) / 63, 0.05 * ((i * 11) % 64) / 63
        frame = round(float(landed) * 60)
        y = cb.evaluate({"t": np.array([frame - 1, frame]) / 60, "v0": v0, "a": a, "k": k})["y"]
        assert y[1] < 0 and (frame == 1 or y[0] >= 0), (shot, landed, y)
    assert re.search(r"11584 calls, \S+ us per call \(checksum \S+, status bits 0\)", out), out
