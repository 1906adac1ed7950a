"""Fuzz suite: hostile specs, arguments and CSV for every command.

The invariant, whatever the input: exit status 0, 1 or 2 (never the internal
error's 70), at most one ``Error:`` line on stderr, no ``Traceback`` anywhere,
no partial or temporary file left next to an output.

Budget: about a minute in CI (the ``ci`` profile). For a longer local run::

    PGD_FUZZ=long PGD_FUZZ_EXAMPLES=10000 python -m pytest -q tests/cli/test_fuzz.py   # ~10 minutes

The ``long`` profile is randomized (a new seed every run) and runs ``PGD_FUZZ_EXAMPLES``
(default 2000) examples per cheap test, a fifth of them for those that solve or draw.
"""

from __future__ import annotations

import io
import os
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pgdcli.driver
from pgdcli.cli import query as _query
from pgdcli.cli.main import cli
from pgdcli.errors import PgdError, SolverError
from pgdcli.problem.spec import parse_spec

ROOT = Path(__file__).resolve().parents[2]
PROBLEMS = ROOT / "problems"

LONG = os.environ.get("PGD_FUZZ", "") == "long"
EXAMPLES = int(os.environ.get("PGD_FUZZ_EXAMPLES", "2000")) if LONG else 0


def budget(ci: int, heavy: bool = False) -> settings:
    """``ci`` examples in CI; ``PGD_FUZZ=long``: ``PGD_FUZZ_EXAMPLES`` (a fifth for heavy tests)."""
    n = max(ci, EXAMPLES // 5 if heavy else EXAMPLES) if LONG else ci
    return settings(max_examples=n, deadline=None, derandomize=not LONG, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                           HealthCheck.data_too_large, HealthCheck.filter_too_much])


def check_result(code: int, out: str, err: str) -> None:
    """The invariant of every command."""
    assert code in (0, 1, 2), (code, err[-2000:])
    assert "Traceback" not in err and "Traceback" not in out, err[-2000:]
    errors = [line for line in err.splitlines() if line.startswith("Error:")]
    assert len(errors) <= 1, err[-2000:]
    if code == 2:
        assert len(errors) == 1, err[-2000:]


def invoke(args, input=None):
    result = CliRunner().invoke(cli, args, input=input, catch_exceptions=True)
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception  # escaped the guard
    check_result(result.exit_code, result.stdout, result.stderr)
    return result


def no_leftovers(directory: Path) -> None:
    leftovers = [p.name for p in directory.iterdir() if p.name.startswith(".") or p.name.endswith((".tmp", ".probe"))]
    assert not leftovers, leftovers


# ----------------------------------------------------------------------------------------------
# strategies
# ----------------------------------------------------------------------------------------------
SHIPPED_TEXTS = [p.read_text() for p in sorted(PROBLEMS.glob("*.yaml"))]
NASTY_SCALARS = ["1e400", "-1e400", ".nan", ".inf", "nan", "0", "-0", "1e-320", "9" * 400, "0x1F", "0o17",
                 "!!binary aGVsbG8=", "!!python/object:os.system x", "!!set {a, b}", "!!timestamp 2001-12-14", "!!timestamp x", "!!bool maybe", "!!int 0x", "!!binary %",
                 "!!timestamp 2001-99-99", "!!omap [1]", "!!pairs {a: 1}", "!!float",
                 "~", "null", "yes", "on", "'x' * 9", "[", "]", "{", "&a", "*a", "*undefined", "<<: *a",
                 "\"\\x00\"", "\"\\uffff\"", "?", "- - -", "|", ">", "%YAML 1.1", "---", "...", "'", '"', "@", "`",
                 "der(u)", "der(u, x, 2)", "__import__('os')", "exp(1e308)", "1/0", "(" * 200 + ")" * 200,
                 "k" * 5000, "u**99999", "a.b", "sin(k*t)", "pi**pi**pi"]


def bomb(levels: int) -> str:
    parts = ['&b0 ["x","x","x","x","x","x","x","x","x"]']
    parts += [f"&b{i} [" + ",".join([f"*b{i - 1}"] * 9) + "]" for i in range(1, levels)]
    return "[" + ", ".join(parts) + "]"


@st.composite
def hostile_yaml(draw) -> str:
    """A shipped spec with lines replaced, values swapped for nasty ones, bombs or deep nesting added."""
    lines = draw(st.sampled_from(SHIPPED_TEXTS)).splitlines()
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(["value", "line", "delete", "bomb", "deep", "raw", "indent"]))
        i = draw(st.integers(0, max(0, len(lines) - 1))) if lines else 0
        if kind == "value" and lines and ":" in lines[i]:
            key = lines[i].split(":", 1)[0]
            lines[i] = f"{key}: {draw(st.sampled_from(NASTY_SCALARS))}"
        elif kind == "line":
            lines.insert(i, draw(st.sampled_from(NASTY_SCALARS)))
        elif kind == "delete" and lines:
            del lines[i]
        elif kind == "bomb" and lines and ":" in lines[i]:
            key = lines[i].split(":", 1)[0]
            lines[i] = f"{key}: {bomb(draw(st.integers(2, 9)))}"
        elif kind == "deep":
            depth = draw(st.integers(10, 3000))
            lines.append(f"{draw(st.sampled_from(['description', 'constants', 'solver', 'junk']))}: "
                         + "[" * depth + "]" * depth)
        elif kind == "raw":
            lines.insert(i, draw(st.text(max_size=40)))
        elif kind == "indent" and lines:
            lines[i] = " " * draw(st.integers(0, 6)) + lines[i].lstrip()
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------
# specs
# ----------------------------------------------------------------------------------------------
@budget(250)
@given(text=st.one_of(hostile_yaml(), st.text(max_size=300)))
def test_parse_spec_raises_only_spec_errors(text):
    try:
        parse_spec(text, source="fuzz.yaml")
    except PgdError as exc:
        message = str(exc)
        assert "\n" not in message.strip() and len(message) < 2000, message[:300]


@budget(60)
@given(data=st.one_of(hostile_yaml().map(str.encode), st.binary(max_size=200)))
def test_solve_cli_on_hostile_specs(tmp_path_factory, monkeypatch, data):
    """``pgd solve`` up to the solver (replaced: the invariant is about input handling, not solving)."""
    def stub(problem, **kwargs):
        raise SolverError("fuzz stub: not solving")

    monkeypatch.setattr(pgdcli.driver, "solve", stub)
    work = tmp_path_factory.mktemp("solve")
    spec = work / "fuzz.yaml"
    spec.write_bytes(data)
    result = invoke(["solve", str(spec), "-o", str(work / "out" / "x.h5"), "-q"])
    assert result.exit_code == 2
    assert not (work / "out" / "x.h5").exists()
    no_leftovers(work)


# ----------------------------------------------------------------------------------------------
# query arguments and CSV, on both paths (lean and click)
# ----------------------------------------------------------------------------------------------
NUMBERS = ["0", "1", "2", "0.3", "4", "-1", "1e308", "-1e308", "nan", "inf", "-inf", "1e-320", "0x10", "1_0",
           "", " ", "abc", "1,2", "0:4:3", "0:4:0", "0:4:-1", "0:4:1e3", "0:4:99999999999999999999", "1:2",
           "1:2:3:4", ",", "1,,2", "٣", "１", "\x00", "0:4:100", "1e5:1:2", "2,2,2"]
TOKENS = ["--t", "--k", "--c", "--x", "--", "-", "-h", "--format", "--field", "--points", "--format=csv",
          "--format=json", "--field=x", "--field=v", "--field=q", "--t=1", "--k=2", "--c=0.3", "x", "v", "plain",
          "csv", "json", "xml", "--help", "--debug", "-V", "—t"]


@pytest.fixture(scope="module")
def spring(codebook_path):
    return str(codebook_path("spring"))


@budget(300)
@given(args=st.lists(st.one_of(st.sampled_from(TOKENS), st.sampled_from(NUMBERS), st.text(max_size=8)),
                     max_size=10))
def test_query_arguments(spring, monkeypatch, args):
    monkeypatch.setenv("PGD_QUERY_MAX_POINTS", "5000")
    invoke(["query", spring, *args])


@budget(150)
@given(args=st.lists(st.one_of(st.sampled_from(TOKENS), st.sampled_from(NUMBERS)), max_size=10))
def test_query_lean_path(spring, monkeypatch, args):
    """The lean path prints a full answer or nothing at all (and then click runs)."""
    monkeypatch.setenv("PGD_QUERY_MAX_POINTS", "5000")
    out, err = io.StringIO(), io.StringIO()
    monkeypatch.setattr(sys, "stdout", out)
    monkeypatch.setattr(sys, "stderr", err)
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"t,k,c\n1,2,0.3\n"), encoding="utf-8"))
    code = _query.run(["query", spring, *args])
    monkeypatch.setattr(sys, "stdout", sys.__stdout__)
    monkeypatch.setattr(sys, "stderr", sys.__stderr__)
    if code is None:
        assert out.getvalue() == "" and err.getvalue() == ""
    else:
        check_result(code, out.getvalue(), err.getvalue())


CELLS = st.one_of(st.sampled_from(["1", "2", "0.3", "0.1", "4", "nan", "inf", "", " 1 ", '"2"', "1e999", "x",
                                   "\x00", "-0", "0.5", "3"]), st.text(max_size=6))


@st.composite
def hostile_csv(draw) -> bytes:
    header = draw(st.one_of(st.just(["t", "k", "c"]), st.permutations(["t", "k", "c"]).map(list),
                            st.lists(st.sampled_from(["t", "k", "c", "x", "", " t"]), max_size=4)))
    rows = draw(st.lists(st.lists(CELLS, min_size=0, max_size=4), max_size=8))
    text = ",".join(header) + "\n" + "".join(",".join(r) + draw(st.sampled_from(["\n", "\r\n", "\n\n"]))
                                             for r in rows)
    data = text.encode("utf-8", "surrogatepass") if draw(st.booleans()) else text.encode("utf-8", "replace")
    prefix = draw(st.sampled_from([b"", b"\xef\xbb\xbf", b"\xff\xfe", b"\x00", b"\x80"]))
    return prefix + data


@budget(200)
@given(data=st.one_of(hostile_csv(), st.binary(max_size=120)), fmt=st.sampled_from(["plain", "csv", "json"]),
       stdin=st.booleans())
def test_query_points_csv(spring, tmp_path_factory, data, fmt, stdin):
    if stdin:
        invoke(["query", spring, "--points", "-", "--format", fmt], input=data)
    else:
        pts = tmp_path_factory.mktemp("pts") / "p.csv"
        pts.write_bytes(data)
        invoke(["query", spring, "--points", str(pts), "--format", fmt])


# ----------------------------------------------------------------------------------------------
# info, verify, plot
# ----------------------------------------------------------------------------------------------
@budget(60)
@given(args=st.lists(st.sampled_from(["--format", "json", "text", "xml", "--help", "-q", "x", "--format=json"]),
                     max_size=4),
       target=st.sampled_from(["cb", "missing", "dir", "spec", "empty", "garbage"]))
def test_info_arguments(spring, tmp_path_factory, args, target):
    work = tmp_path_factory.mktemp("info")
    paths = {"cb": spring, "missing": str(work / "no.h5"), "dir": str(work), "spec": str(PROBLEMS / "spring.yaml")}
    (work / "empty.h5").write_bytes(b"")
    (work / "garbage.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + os.urandom(64))
    paths.update(empty=str(work / "empty.h5"), garbage=str(work / "garbage.h5"))
    invoke(["info", paths[target], *args])


VERIFY_OPTIONS = st.lists(st.sampled_from([
    ["--samples", "1"], ["--samples", "0"], ["--samples", "-3"], ["--samples", "x"], ["--sampling", "lhs"],
    ["--sampling", "grid"], ["--seed", "7"], ["--seed", "-1"], ["--times", "0"], ["--times", "2"],
    ["--method", "RK45"], ["--method", "rk45"], ["--method", "Euler"], ["--rtol", "0"], ["--rtol", "1e-6"],
    ["--rtol", "nan"], ["--atol", "2"], ["--max-error", "1e-30"], ["--max-error", "inf"], ["--max-error", "nan"],
    ["--max-rel-error", "-1"], ["--format", "json"], ["--format", "yaml"], ["-j", "0"], ["--points", "{pts}"],
    ["--points", "{missing}"], ["--points", "{bad}"]]), max_size=4)


@budget(40, heavy=True)
@given(options=VERIFY_OPTIONS, bad=hostile_csv())
def test_verify_arguments(codebook_path, tmp_path_factory, options, bad):
    work = tmp_path_factory.mktemp("verify")
    (work / "pts.csv").write_text("k\n2\n5\n")
    (work / "bad.csv").write_bytes(bad.replace(b"t,", b"", 1))
    fills = {"pts": str(work / "pts.csv"), "missing": str(work / "none.csv"), "bad": str(work / "bad.csv")}
    args = [a.format(**fills) for option in options for a in option]
    if "--samples" not in args:
        args += ["--samples", "2"]
    invoke(["verify", str(codebook_path("parametric")), "-j", "1", "-q", "--times", "1", *args])


PLOT_OPTIONS = st.lists(st.sampled_from([
    ["--kind", "modes"], ["--kind", "convergence"], ["--kind", "solution"], ["--kind", "error"], ["--kind", "x"],
    ["--count", "2"], ["--count", "0"], ["--count", "-1"], ["--field", "u"], ["--field", "w"], ["--at", "k=2"],
    ["--at", "k=99"], ["--at", "k"], ["--at", "=,="], ["--over", "t,k"], ["--over", "t,t"], ["--over", "k"],
    ["--fix", "k=2"], ["--fix", "q=1"], ["--points", "3"], ["--points", "0"], ["--points", "100000000"],
    ["--dpi", "5"], ["--dpi", "20"], ["--size", "2x2"], ["--size", "0x0"], ["--size", "1e9x1"], ["--size", "x"],
    ["--reference"], ["-o", "{dir}/a.svg"], ["-o", "{dir}/new/b.png"], ["-o", "{dir}/c.txt"], ["-o", "{dir}"],
    ["-o", "/proc/x.png"], ["-o", "/dev/null"]]), max_size=4)


@budget(30, heavy=True)
@given(options=PLOT_OPTIONS)
def test_plot_arguments(codebook_path, tmp_path_factory, options):
    work = tmp_path_factory.mktemp("plot")
    args = [a.format(dir=work) for option in options for a in option]
    if "-o" not in args:
        args += ["-o", str(work / "default.png")]
    if "--points" not in args:  # small pictures: fast examples
        args += ["--points", "5"]
    if "--dpi" not in args:
        args += ["--dpi", "20"]
    if "--size" not in args:
        args += ["--size", "2x2"]
    invoke(["plot", str(codebook_path("parametric")), *args])
    for directory in (work, work / "new"):
        if directory.is_dir():
            no_leftovers(directory)
