"""Ctrl-C ends every command with exit status 130 and one line, ``Error: interrupted``.

Each command runs in a child process whose first slow call (loading the codebook, or the solve)
is replaced by one that announces itself and waits; the test then sends SIGINT, as a terminal's
Ctrl-C does.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

CHILD = """
import sys, time
import pgdcli.driver, pgdcli.codebook.codebook as cb

def wait(*args, **kwargs):
    sys.stderr.write("ready\\n")
    sys.stderr.flush()
    time.sleep(60)

pgdcli.driver.solve = wait
cb.Codebook.load = classmethod(lambda cls, *a, **k: wait())
from pgdcli.cli.entry import main
main(sys.argv[1:])
"""

COMMANDS = {
    "solve": ["solve", str(ROOT / "problems" / "spring.yaml"), "-o", "{tmp}/x.h5", "-q"],
    "query": ["query", "{tmp}/cb.h5", "--t", "1", "--k", "2"],
    "verify": ["verify", "{tmp}/cb.h5"],
    "info": ["info", "{tmp}/cb.h5"],
    "plot": ["plot", "{tmp}/cb.h5", "-o", "{tmp}/x.png"],
    "fit": ["fit", "{tmp}/cb.h5", "{tmp}/data.csv"],
    "export": ["export", "{tmp}/cb.h5", "--to", "c"],
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_ctrl_c_is_exit_130_with_one_line(tmp_path, command):
    (tmp_path / "cb.h5").write_bytes(b"not read: the load waits first")
    (tmp_path / "data.csv").write_text("t,x\n0,1\n")
    args = [a.format(tmp=tmp_path) for a in COMMANDS[command]]
    child = subprocess.Popen([sys.executable, "-c", CHILD, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    try:
        assert child.stderr.readline() == "ready\n"
        child.send_signal(signal.SIGINT)
        out, err = child.communicate(timeout=60)
    finally:
        child.kill()
    assert child.returncode == 130, (child.returncode, err)
    assert err.splitlines() == ["Error: interrupted"] and out == ""
