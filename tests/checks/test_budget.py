"""Work over a documented limit is refused before it starts, naming the key, the estimate and the limit."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import spec_text
from pgdcli.checks.budget import check_budget, fastest_rate
from pgdcli.cli.main import cli
from pgdcli.errors import LimitError
from pgdcli.problem.spec import parse_spec


def chain(n: int, t_nodes: str = "auto") -> str:
    unknowns = "\n".join(f"  u{i}: {{initial: 1}}" for i in range(n))
    equations = "\n".join(f'  - "der(u{i}) = -k*u{i} + u{(i + 1) % n}"' for i in range(n))
    return (f"name: chain\ncoordinates:\n  t: {{domain: [0, 1], nodes: {t_nodes}}}\n  k: {{domain: [1, 2]}}\n"
            f"unknowns:\n{unknowns}\nequations:\n{equations}\n")


def wide(d: int) -> str:
    coords = "\n".join(f"  p{i}: {{domain: [1, 2]}}" for i in range(d))
    rate = "+".join(f"p{i}" for i in range(d))
    return (f"name: wide\ncoordinates:\n  t: {{domain: [0, 1]}}\n{coords}\nunknowns:\n  u: {{initial: 1}}\n"
            f"equations:\n  - \"der(u) = -({rate})*u\"\n")


OSCILLATOR = """name: long
coordinates:
  t: {domain: [0, END]}
  k: {domain: [1, 2]}
unknowns:
  x: {initial: 1}
  v: {initial: 0}
equations:
  - "der(x) = v"
  - "der(v) = -k*x"
"""

SLABS = """name: slabs
coordinates:
  t: {domain: [0, 1]}
  k: {domain: [1, 2]}
unknowns:
  u: {initial: 1}
equations:
  - "der(u) = -k*u"
solver:
  time_slabs: 1000000000
"""

HUGE = {
    "a billion time slabs": (SLABS, "solver.time_slabs", "PGD_MAX_TIME_NODES"),
    "1000 unknowns": (chain(1000), "unknowns", "at most 256"),
    "51 coordinates": (wide(50), "coordinates", "at most 30"),
    "t up to 1e9": (OSCILLATOR.replace("END", "1000000000"), "coordinates.t.domain", "PGD_MAX_PERIODS"),
    "100 unknowns x 100 time nodes": (chain(100, "100"), "unknowns", "PGD_MAX_STATE_SIZE"),
}


@pytest.mark.parametrize("kind", sorted(HUGE))
def test_enormous_work_is_refused_in_the_cli_before_any_solve(tmp_path, kind):
    text, key, limit = HUGE[kind]
    path = tmp_path / "spec.yaml"
    path.write_text(text)
    started = time.process_time()  # CPU seconds: the machine may be shared, the work is what is bounded
    result = CliRunner().invoke(cli, ["solve", str(path), "-o", str(tmp_path / "out.h5")])
    elapsed = time.process_time() - started
    assert result.exit_code == 2, (result.exit_code, result.stderr)
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and key in lines[0] and limit in lines[0], lines
    assert elapsed < 2.0, elapsed
    assert not (tmp_path / "out.h5").exists()


def test_dense_operators_beyond_the_memory_limit_are_refused(monkeypatch):
    problem = parse_spec(chain(60), source="chain.yaml")  # 180 terms on a state of 540 values: 0.39 GiB
    check_budget(problem, march=False)
    check_budget(problem, march=True)  # the march has no dense state
    monkeypatch.setenv("PGD_MAX_WORK_BYTES", str(2**28))
    with pytest.raises(LimitError, match=r"equations: 180 linear terms .* 0\.391 GiB .*PGD_MAX_WORK_BYTES"):
        check_budget(problem, march=False)


def test_the_fastest_rate_is_the_oscillators_frequency():
    problem = parse_spec(OSCILLATOR.replace("END", "10"), source="osc.yaml")
    assert fastest_rate(problem) == pytest.approx(math.sqrt(2.0), rel=1e-6)  # k = 2 at a corner


def test_a_limit_follows_its_override(monkeypatch):
    problem = parse_spec(OSCILLATOR.replace("END", "100000"), source="osc.yaml")  # ~2.2e4 periods
    with pytest.raises(LimitError, match="PGD_MAX_PERIODS"):
        check_budget(problem, march=False)
    monkeypatch.setenv("PGD_MAX_PERIODS", "1e5")
    check_budget(problem, march=False)
    monkeypatch.setenv("PGD_MAX_PERIODS", "-3")
    with pytest.raises(Exception, match="PGD_MAX_PERIODS"):
        check_budget(problem, march=False)


def test_shipped_sizes_pass(write_spec):
    problem = parse_spec(spec_text(), source="base.yaml")
    check_budget(problem, march=False)
    check_budget(problem, march=True)
