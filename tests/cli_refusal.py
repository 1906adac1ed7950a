"""``pgd solve`` in a subprocess, held to the refusal contract: exit 2, one ``Error:`` line, nothing written."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def pgd_solve(spec: Path, out: Path) -> subprocess.CompletedProcess:
    """``pgd solve SPEC -o OUT -q`` in a fresh interpreter (the real entry point, exit status and streams)."""
    return subprocess.run([sys.executable, "-c", "from pgdcli.cli.entry import main; main()", "solve", str(spec),
                           "-o", str(out), "-q"], capture_output=True, text=True)


def assert_refused_in_one_line(spec: Path, out: Path, reason: str) -> None:
    """``pgd solve`` on ``spec`` exits 2 with one ``Error:`` line holding ``reason``, no traceback, no ``out``."""
    run = pgd_solve(spec, out)
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert run.returncode == 2, run.stderr
    assert len(lines) == 1 and lines[0].startswith("Error: ") and reason in lines[0], lines
    assert "Traceback" not in run.stderr and not out.exists()
