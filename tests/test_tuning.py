"""pgdcli.tuning: the machine-specific constants, their environment overrides and their documentation."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from pgdcli import tuning

ROOT = Path(__file__).resolve().parents[1]


def _python(code: str, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, **env}, cwd=ROOT)


def test_every_constant_is_a_setting_with_its_default():
    assert tuning.SETTINGS, "no settings"
    for name, (default, meaning) in tuning.SETTINGS.items():
        assert getattr(tuning, name) == default, name  # no PGD_ variable in the test environment
        assert isinstance(default, (int, float)) and default > 0 and meaning


def test_an_environment_variable_overrides_a_constant_where_it_is_used():
    run = _python("import pgdcli.tuning as t, pgdcli.codebook.threads as th, pgdcli.codebook.batch_eval as b; "
                  "print(t.MAX_THREADS, th.MAX_THREADS, b.SECONDS_PER_BLOCK)", PGD_MAX_THREADS="1",
                  PGD_SECONDS_PER_BLOCK="2.5e-5")
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["1", "1", "2.5e-05"]


@pytest.mark.parametrize("value", ["abc", "0", "-3", "1.5", "inf", ""])
def test_a_bad_value_names_the_variable(value):
    run = _python("import pgdcli.tuning", PGD_BLOCK_BYTES=value)
    assert run.returncode != 0
    assert ("environment variable PGD_BLOCK_BYTES: expected a positive integer (bytes of a tensor-train batch's "
            f"widest intermediate per block; default 1572864), got {value!r}") in run.stderr


def test_a_bad_value_is_one_error_line_from_the_command_line(tmp_path):
    """pgd query (its lean path, then the click command) reports it as bad input: exit 2, no traceback."""
    run = _python(f"from pgdcli.cli.entry import main; main(['query', {str(tmp_path / 'x.h5')!r}, '--t', '0'])",
                  PGD_MAX_CHUNK="many")
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr == ("Error: environment variable PGD_MAX_CHUNK: expected a positive integer (most points in a CP "
                          "batch's chunk; default 4096), got 'many'\n")


def test_the_documentation_lists_every_setting_with_its_default():
    text = (ROOT / "docs" / "tuning.md").read_text()
    rows = dict(re.findall(r"^\| `PGD_([A-Z_]+)` \| `([^`]+)` \|", text, flags=re.M))
    assert set(rows) == set(tuning.SETTINGS)
    for name, (default, _) in tuning.SETTINGS.items():
        assert float(rows[name]) == default, name
