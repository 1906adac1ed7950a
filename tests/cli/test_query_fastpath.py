"""The lean ``pgd query`` (pgdcli.cli.query) and the fast evaluation paths of Codebook.

``pgd query`` runs without click when it can (the console script's entry point is
``pgdcli.cli.entry:main``). These tests hold it to three things:

- byte-identical output: for plain / csv / json, lists, ranges, ``--field``,
  ``--points`` (file and stdin), the lean path prints exactly what the
  in-process ``Codebook.evaluate`` gives (formatted as documented: ``repr`` of
  the floats) and exactly what the click command prints;
- anything else (errors, help, odd options) falls back to click, having
  printed nothing, so messages and exit codes are click's own;
- a lean import set: no click, rich or scipy.

And the evaluation paths of Codebook (one point, broadcasting, chunks,
threads) agree bitwise with each other and with the plain algorithm
(``interpolation_matrix @ modes``, product over coordinates, ``@ alphas``).
"""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import pgdcli.codebook.point as point_module
import pgdcli.codebook.threads as threads_module
from pgdcli.codebook import batch_eval
from pgdcli.cli import query as _query
from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook, CoordinateInfo, CPTensor
from pgdcli.errors import QueryError

SPRING_CASES = [
    ["--t", "1", "--k", "2", "--c", "0.3"],
    ["--t", "0", "--k", "1", "--c", "0.1"],  # a corner: nodes in every coordinate
    ["--t", "4", "--k", "4", "--c", "0.5"],
    ["--t", "0:4:41", "--k", "2", "--c", "0.3"],
    ["--t", "0:4:41", "--k", "2", "--c", "0.3", "--field", "x", "--format", "csv"],
    ["--t", "0:4:7", "--k", "1,2.5,4", "--c", "0.1,0.5", "--format", "json"],
    ["--t", "0:4:7", "--k", "1,2.5,4", "--c", "0.1,0.5", "--format", "csv", "--field", "v", "--field", "x"],
    ["--t=1.5", "--k=2", "--c=0.25"],
    ["--format", "csv", "--t", "1", "--k", "2", "--c", "0.3"],
    ["--t", "1", "--format=json", "--k", "2", "--c", "0.3", "--field=v"],
    ["--c", "0.3", "--k", "2", "--t", "0.5,1.5,2.5"],
    ["--t", "0:4:101", "--k", "1:4:31", "--c", "0.3"],
    ["--t", "0:4:3", "--k", "1:4:3", "--c", "0.1:0.5:3", "--format", "csv"],
    ["--t", "1", "--k", "2", "--c", "0.3", "--field", "v", "--field", "x", "--field", "v"],
]

POINTS_CSV = "t,k,c\n0.5,2,0.3\n1.7,3.9,0.1\n4,1,0.5\n\n0,2.5,0.2\n"


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------
def _lean(argv, monkeypatch, stdin_text=None):
    """Run pgdcli.cli.query.run in-process: (exit status or None, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    monkeypatch.setattr(sys, "stdout", out)
    monkeypatch.setattr(sys, "stderr", err)
    if stdin_text is not None:
        stdin = io.TextIOWrapper(io.BytesIO(stdin_text.encode()), encoding="utf-8")
        monkeypatch.setattr(sys, "stdin", stdin)
    code = _query.run([str(a) for a in argv])
    monkeypatch.undo()
    return code, out.getvalue(), err.getvalue()


def _click(argv, stdin_text=None):
    result = CliRunner().invoke(cli, [str(a) for a in argv], prog_name="pgd", input=stdin_text)
    return result.exit_code, result.stdout, result.stderr


def _coordinate_values(cb, args):
    """--NAME VALUE pairs -> {name: 1-D values}, parsed independently of pgdcli."""
    given, i = {}, 0
    while i < len(args):
        arg = args[i]
        if arg in ("--format", "--field"):
            i += 2
            continue
        if arg.startswith(("--format=", "--field=")):
            i += 1
            continue
        name, eq, value = arg[2:].partition("=")
        if not eq:
            value, i = args[i + 1], i + 1
        i += 1
        if ":" in value:
            a, b, n = value.split(":")
            given[name] = np.linspace(float(a), float(b), int(n))
        else:
            given[name] = np.array([float(v) for v in value.split(",")])
    return {n: given[n] for n in cb.coordinate_names}


def _options(args):
    fmt, fields, i = "plain", [], 0
    while i < len(args):
        if args[i] == "--format":
            fmt, i = args[i + 1], i + 2
        elif args[i] == "--field":
            fields.append(args[i + 1])
            i += 2
        elif args[i].startswith("--format="):
            fmt, i = args[i].split("=", 1)[1], i + 1
        elif args[i].startswith("--field="):
            fields.append(args[i].split("=", 1)[1])
            i += 1
        else:
            i += 1
    return fmt, fields


def _expected_text(cb, points, fmt, fields):
    """The documented output: Codebook.evaluate on each point alone (one point, one output; repr of float64)."""
    names = list(fields) if fields else cb.unknown_names
    coords = cb.coordinate_names
    n = len(next(iter(points.values())))
    rows = []
    for i in range(n):
        values = cb.evaluate({c: float(points[c][i]) for c in coords}, fields=names)
        rows.append([float(values[u]) for u in names])
    pts = [[float(points[c][i]) for c in coords] for i in range(n)]
    if fmt == "plain":
        return "".join(" ".join(repr(v) for v in r) + "\n" for r in rows)
    if fmt == "csv":
        return ",".join(coords + names) + "\n" + "".join(",".join(repr(v) for v in p + r) + "\n"
                                                         for p, r in zip(pts, rows))
    return json.dumps([dict(zip(coords + names, p + r)) for p, r in zip(pts, rows)]) + "\n"


def _product(cb, lists):
    grids = np.meshgrid(*[lists[n] for n in cb.coordinate_names], indexing="ij")
    return {n: g.reshape(-1) for n, g in zip(cb.coordinate_names, grids)}


# ----------------------------------------------------------------------------------------------
# byte-identical output
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("args", SPRING_CASES, ids=lambda a: " ".join(a))
def test_lean_query_output_is_byte_identical(codebook_path, monkeypatch, args):
    path = codebook_path("spring")
    cb = Codebook.load(path)
    code, out, err = _lean(["query", path, *args], monkeypatch)
    assert code == 0 and err == ""
    fmt, fields = _options(args)
    assert out == _expected_text(cb, _product(cb, _coordinate_values(cb, args)), fmt, fields)
    assert _click(["query", path, *args]) == (0, out, "")


@pytest.mark.parametrize("name,args", [
    ("relaxation", ["--t", "1", "--k", "2", "--a", "0.5", "--u0", "0.3"]),
    ("relaxation", ["--t", "0:3:5", "--k", "0.5,5", "--a", "-1:1:3", "--u0", "0,1", "--format", "csv"]),
    ("relaxation", ["--t", "0:3:4", "--k", "0.5:5:4", "--a", "-1", "--u0", "0.25", "--format", "json"]),
    ("parametric", ["--t", "0:10:11", "--k", "2"]),
    ("parametric", ["--t", "0:10:5", "--k", "1:10:4", "--format", "csv"]),
    ("parametric", ["--t", "5", "--k", "2"]),
])
def test_lean_query_other_codebooks(codebook_path, monkeypatch, name, args):
    path = codebook_path(name)
    cb = Codebook.load(path)
    code, out, err = _lean(["query", path, *args], monkeypatch)
    assert code == 0 and err == ""
    fmt, fields = _options(args)
    assert out == _expected_text(cb, _product(cb, _coordinate_values(cb, args)), fmt, fields)
    assert _click(["query", path, *args]) == (0, out, "")


@pytest.mark.parametrize("fmt", ["plain", "csv", "json"])
@pytest.mark.parametrize("stdin", [False, True])
def test_lean_query_points(codebook_path, monkeypatch, tmp_path, fmt, stdin):
    path = codebook_path("spring")
    cb = Codebook.load(path)
    csv_path = tmp_path / "points.csv"
    csv_path.write_text(POINTS_CSV)
    source = "-" if stdin else csv_path
    args = ["query", path, "--points", source, "--format", fmt, "--field", "v", "--field", "x"]
    code, out, err = _lean(args, monkeypatch, stdin_text=POINTS_CSV if stdin else None)
    assert code == 0 and err == ""
    rows = np.array([[float(v) for v in line.split(",")] for line in POINTS_CSV.splitlines()[1:] if line])
    points = {n: rows[:, j] for j, n in enumerate(["t", "k", "c"])}
    assert out == _expected_text(cb, points, fmt, ["v", "x"])
    assert _click(args, stdin_text=POINTS_CSV if stdin else None) == (0, out, "")


def test_lean_query_large_grid_matches_flat_evaluation(codebook_path, monkeypatch):
    """A grid big enough for the chunked, threaded batch path."""
    path = codebook_path("spring")
    cb = Codebook.load(path)
    args = ["--t", "0:4:97", "--k", "1:4:13", "--c", "0.1:0.5:7"]
    code, out, _ = _lean(["query", path, *args], monkeypatch)
    assert code == 0
    assert out == _expected_text(cb, _product(cb, _coordinate_values(cb, args)), "plain", [])


# ----------------------------------------------------------------------------------------------
# everything else goes to click, untouched
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("args", [
    ["--t", "5", "--k", "2", "--c", "0.3"],
    ["--t", "1", "--k", "2"],
    ["--t", "1", "--k", "2", "--c", "0.3", "--z", "1"],
    ["--t", "1", "--k", "2", "--c", "0.3", "--field", "w"],
    ["--t", "abc", "--k", "2", "--c", "0.3"],
    ["--t", "1:2", "--k", "2", "--c", "0.3"],
    ["--t", "1", "--k", "2", "--c", "0.3", "--t", "2"],
    ["--t", "1", "--k", "2", "--c"],
    ["--t", "1", "--k", "2", "--c", "0.3", "extra"],
    ["--t", "1", "--k", "2", "--c", "0.3", "--format", "xml"],
    ["--t", "1", "--k", "2", "--c", "0.3", "--format"],
    ["--t", "nan", "--k", "2", "--c", "0.3"],
    ["--help"],
    ["--t", "1", "--k", "2", "--c", "0.3", "-h"],
    ["--", "--t", "1", "--k", "2", "--c", "0.3"],
    ["--points", "missing.csv"],
])
def test_lean_query_leaves_the_rest_to_click(codebook_path, monkeypatch, args):
    path = codebook_path("spring")
    assert _lean(["query", path, *args], monkeypatch) == (None, "", "")


@pytest.mark.parametrize("text", ["t,k\n1,2\n", "t,k,c\n1,2,x\n", "", "t,k,c\n1,2\n"])
def test_lean_query_points_errors_replay_stdin_to_click(codebook_path, monkeypatch, text):
    """A bad --points - falls back to click, which reads the same input and reports it."""
    path = codebook_path("spring")
    expected = _click(["query", path, "--points", "-"], stdin_text=text)
    assert expected[0] == 2 and expected[2].startswith("Error: stdin: ")
    out, err = io.StringIO(), io.StringIO()
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(text.encode()), encoding="utf-8"))
    monkeypatch.setattr(sys, "stdout", out)
    monkeypatch.setattr(sys, "stderr", err)
    code = _query.run(["query", str(path), "--points", "-"])
    assert code is None and out.getvalue() == "" and err.getvalue() == ""
    replay = sys.stdin.read()  # what click gets
    monkeypatch.undo()
    assert replay == text


def test_lean_query_ignores_other_commands():
    for argv in ([], ["query"], ["info", "x.h5"], ["--version"], ["solve", "spec.yaml"], ["query", "--t", "1"]):
        assert _query.run(argv) is None


def _console_script():
    exe = shutil.which("pgd")
    if exe is None:
        pytest.skip("pgd console script not on PATH")
    return exe


@pytest.mark.parametrize("args,stdin", [
    (["--t", "0:4:5", "--k", "2", "--c", "0.3", "--format", "csv"], None),
    (["--points", "-", "--format", "json"], POINTS_CSV),
    (["--t", "5", "--k", "2", "--c", "0.3"], None),            # out of domain: click's error
    (["--t", "1", "--k", "2", "--c", "0.3", "--format", "xml"], None),
    (["--points", "-"], "t,k\n1,2\n"),                         # stdin replayed to click
])
def test_console_script_matches_click(codebook_path, args, stdin):
    exe = _console_script()
    path = codebook_path("spring")
    proc = subprocess.run([exe, "query", str(path), *args], input=stdin, capture_output=True, text=True,
                          timeout=120)
    assert (proc.returncode, proc.stdout, proc.stderr) == _click(["query", path, *args], stdin_text=stdin)


def test_lean_query_imports(codebook_path):
    """No click, rich, scipy (or yaml, matplotlib) on the query path, and no threadpoolctl for small queries."""
    path = codebook_path("spring")
    code = (
        "import sys, io\n"
        "from pgdcli.cli import query as _query\n"
        "sys.stdout = io.StringIO()\n"
        f"assert _query.run(['query', {str(path)!r}, '--t', '0:4:9', '--k', '2', '--c', '0.3']) == 0\n"
        "sys.stdout = sys.__stdout__\n"
        "print(' '.join(sorted({m.split('.')[0] for m in sys.modules})))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    loaded = set(proc.stdout.split())
    assert "numpy" in loaded and "h5py" in loaded
    for heavy in ("click", "rich", "scipy", "yaml", "matplotlib", "threadpoolctl", "pathlib", "tempfile"):
        assert heavy not in loaded, heavy


# ----------------------------------------------------------------------------------------------
# Codebook evaluation paths agree bitwise
# ----------------------------------------------------------------------------------------------
def _plain_evaluation(cb, points):
    """The textbook algorithm on flat points: per coordinate interpolation_matrix @ modes, product, @ alphas."""
    product = None
    for c, basis in zip(cb.coordinates, cb._bases):
        modes = np.hstack([cb.fields[u].factors[cb.coordinate_names.index(c.name)] for u in cb.fields])
        vals = basis.interpolation_matrix(np.clip(points[c.name], *c.domain)) @ modes
        product = vals if product is None else product * vals
    out, start = {}, 0
    for u, fm in cb.fields.items():
        out[u] = product[:, start:start + fm.rank] @ fm.weights
        start += fm.rank
    return out


def _with_nodes(cb, points, rng, fraction=0.2):
    for c, basis in zip(cb.coordinates, cb._bases):
        x = points[c.name]
        hit = rng.random(x.size) < fraction
        x[hit] = basis.nodes[rng.integers(0, basis.size, hit.sum())]
    return points


@pytest.mark.parametrize("name", ["spring", "relaxation", "parametric"])
def test_one_point_is_the_plain_algorithm_bitwise(solved, name):
    cb = solved(name).codebook
    rng = np.random.default_rng(7)
    for _ in range(300):
        p = _with_nodes(cb, {c.name: rng.uniform(*c.domain, 1) for c in cb.coordinates}, rng, 0.3)
        ref = _plain_evaluation(cb, p)
        scalar = cb(**{k: float(v[0]) for k, v in p.items()})
        array = cb(**p)
        for u in cb.unknown_names:
            assert scalar[u].shape == () and array[u].shape == (1,)
            assert scalar[u].tobytes() == ref[u].tobytes() == array[u].tobytes()


@pytest.mark.parametrize("name", ["spring", "relaxation"])
def test_batches_threads_and_chunks(solved, monkeypatch, name):
    """Threads never change a value; chunk lengths only through the BLAS kernel a product shape takes."""
    cb = solved(name).codebook
    rng = np.random.default_rng(8)
    size = threads_module.PARALLEL_MIN_POINTS + 3 * 1024 + 65
    p = _with_nodes(cb, {c.name: rng.uniform(*c.domain, size) for c in cb.coordinates}, rng)
    ref = cb(**p)
    plain = _plain_evaluation(cb, p)
    for u in cb.unknown_names:
        np.testing.assert_allclose(ref[u], plain[u], rtol=1e-13, atol=1e-13)
    for threads in (1, 2, 3):
        monkeypatch.setattr(threads_module, "available_threads", lambda: threads)
        other = cb(**p)
        for u in cb.unknown_names:
            assert other[u].tobytes() == ref[u].tobytes(), threads
    for chunk_bytes in (1, 1 << 18, 1 << 22):  # chunks of 64 points up to 4096
        monkeypatch.setattr(threads_module, "CHUNK_BYTES", chunk_bytes)
        other = cb(**p)
        for u in cb.unknown_names:
            np.testing.assert_allclose(other[u], ref[u], rtol=1e-14, atol=1e-14)


def test_tensor_train_batches_threads_and_chunks(solved, monkeypatch):
    """The tensor-train batch path: threads never change a value, and batch values agree with
    one-point evaluation (the point past the last full chunk, which joins it, included)."""
    cb = solved("logistic").codebook
    rng = np.random.default_rng(9)
    size = threads_module.PARALLEL_MIN_POINTS + 2 * batch_eval.MAX_BLOCK + 1
    p = {c.name: rng.uniform(*c.domain, size) for c in cb.coordinates}
    ref = cb(**p)
    for i in list(rng.choice(size, 20, replace=False)) + [size - 1]:
        one = cb(**{k: float(v[i]) for k, v in p.items()})
        np.testing.assert_allclose(ref["u"][i], one["u"], rtol=1e-13, atol=1e-14)
    for threads in (1, 2, 3):
        monkeypatch.setattr(threads_module, "available_threads", lambda: threads)
        assert cb(**p)["u"].tobytes() == ref["u"].tobytes(), threads


def test_batch_of_one_chunk_is_the_plain_algorithm_bitwise(solved):
    """Up to one chunk, a batch makes exactly the numpy/BLAS calls of the plain algorithm."""
    cb = solved("spring").codebook
    rng = np.random.default_rng(10)
    chunk = threads_module.chunk_length(cb._stacked[0].shape[1], max(b.size for b in cb._bases))
    for size in (2, 3, 7, 63, 64, 65, chunk - 1, chunk):
        p = _with_nodes(cb, {c.name: rng.uniform(*c.domain, size) for c in cb.coordinates}, rng)
        ours, plain = cb(**p), _plain_evaluation(cb, p)
        for u in cb.unknown_names:
            assert ours[u].tobytes() == plain[u].tobytes(), size


@pytest.mark.parametrize("name", ["spring", "relaxation", "parametric"])
def test_broadcast_inputs_equal_the_flat_grid_bitwise(solved, name):
    cb = solved(name).codebook
    rng = np.random.default_rng(9)
    d = len(cb.coordinates)
    for counts in [(5, 1, 3, 2), (1, 7, 1, 1), (40, 30, 2, 2), (2, 2, 2, 2)]:
        lists = {c.name: np.sort(rng.uniform(*c.domain, n)) for c, n in zip(cb.coordinates, counts)}
        lists = _with_nodes(cb, lists, rng, 0.3)
        shaped = {c.name: lists[c.name].reshape([-1 if i == j else 1 for i in range(d)])
                  for j, c in enumerate(cb.coordinates)}
        grid = cb(**shaped)
        flat = cb(**_product(cb, lists))
        for u in cb.unknown_names:
            assert grid[u].shape == tuple(counts[:d])
            assert grid[u].reshape(-1).tobytes() == flat[u].tobytes()


def test_nodes_are_exact_on_every_path():
    """Small-integer modes: every nodal sum is exact, so nodes must give nodal_values exactly."""
    coords = [CoordinateInfo("t", (0.0, 2.0), 5, "chebyshev", "time"), CoordinateInfo("k", (1.0, 3.0), 4),
              CoordinateInfo("a", (-1.0, 1.0), 3, "linear")]
    rng = np.random.default_rng(0)
    fields = {"u": CPTensor(np.array([1.0, -2.0, 0.5]), tuple(rng.integers(-4, 5, (c.nodes, 3)).astype(float)
                                                                   for c in coords))}
    cb = Codebook(coords, fields)
    nodes = [c.basis().nodes for c in coords]
    nodal = cb.nodal_values("u")
    for index in np.ndindex(*nodal.shape):
        x = {c.name: float(n[i]) for c, n, i in zip(coords, nodes, index)}
        assert float(cb(**x)["u"]) == nodal[index]
        assert float(cb(**{k: np.float64(v) for k, v in x.items()})["u"]) == nodal[index]
    grid = cb(**{c.name: n.reshape([-1 if i == j else 1 for i in range(3)])
                 for j, (c, n) in enumerate(zip(coords, nodes))})["u"]
    assert np.array_equal(grid, nodal)


def test_one_point_errors_match_the_array_path(solved):
    cb = solved("spring").codebook
    for bad in [5.0, -1.0, float("nan"), float("inf"), 4 + 1e-6]:
        messages = []
        for value in (bad, np.float64(bad), [bad], np.array(bad)):
            with pytest.raises(QueryError) as info:
                cb(t=value, k=2.0, c=0.3)
            messages.append(str(info.value))
        assert len(set(messages)) == 1, messages
    # within the rounding slack of the domain: accepted and clipped, as for arrays
    assert cb(t=4 + 1e-13, k=2, c=0.3)["x"].tobytes() == cb(t=[4.0], k=2, c=0.3)["x"].tobytes()


def test_one_point_types(solved):
    cb = solved("parametric").codebook
    for t, k in [(5.0, 2.0), (5, 2), (np.float64(5), 2.0), (True, 2.0), ("5", 2.0)]:
        out = cb(t=t, k=k)["u"]
        assert isinstance(out, np.ndarray) and out.shape == () and out.dtype == np.float64
        assert float(out) == pytest.approx((10.0 / 2.0 - 1.0) * float(t), abs=1e-12)
    assert cb(t=[], k=2.0)["u"].shape == (0,)
    assert cb(t=np.ones((2, 0)), k=2.0)["u"].shape == (2, 0)


def _blas_threads(threadpoolctl):
    return [m["num_threads"] for m in threadpoolctl.threadpool_info() if m["user_api"] == "blas"]


def test_blas_limit_is_restored_after_batches(solved, two_blas_threads):
    threadpoolctl = pytest.importorskip("threadpoolctl")
    cb = solved("spring").codebook
    before = _blas_threads(threadpoolctl)
    assert set(before) == {2}
    for n in (threads_module.BLAS_LIMIT_MIN_POINTS, threads_module.PARALLEL_MIN_POINTS + 1):
        cb(t=np.linspace(0, 4, n), k=np.full(n, 2.0), c=np.full(n, 0.3))
        assert _blas_threads(threadpoolctl) == before
    # batches running at the same time share one limit, lifted when the last one ends
    import threading

    n = threads_module.PARALLEL_MIN_POINTS + 1
    p = {"t": np.linspace(0, 4, n), "k": np.full(n, 2.0), "c": np.full(n, 0.3)}
    ref = cb(**p)["x"]
    results = []
    threads = [threading.Thread(target=lambda: results.append(cb(**p)["x"])) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(results) == 4 and all(r.tobytes() == ref.tobytes() for r in results)
    assert _blas_threads(threadpoolctl) == before
    assert threads_module.blas_users() == 0


# ----------------------------------------------------------------------------------------------
# one tensor-train point (node tables, merged first pair, vector-first cores)
# ----------------------------------------------------------------------------------------------
def _small_tt_codebook(order, first_rank=9):
    """Two tensor-train unknowns of different ranks (zero-padded in the stack) on a piecewise
    time coordinate (3 slabs of 5 nodes), a Chebyshev and a linear one, cores in ``order``."""
    from pgdcli.codebook.codebook import TT

    coords = [CoordinateInfo("t", (0.0, 3.0), 13, "chebyshev", "time", breakpoints=(0.0, 0.7, 1.9, 3.0)),
              CoordinateInfo("x", (-1.0, 2.0), 7, "chebyshev"),
              CoordinateInfo("y", (0.5, 1.5), 6, "linear")]
    rng = np.random.default_rng(12)
    fields = {}
    for name, ranks in (("u", (1, first_rank, 4, 1)), ("w", (1, first_rank - 2, 3, 1))):
        cores = tuple(rng.standard_normal((ranks[k], coords[j].nodes, ranks[k + 1]))
                      for k, j in enumerate(order))
        fields[name] = TT(cores, order)
    return Codebook(coords, fields, name="small-tt", report={})


def _direct_tt(cb, point):
    """The tensor train at one point by plain numpy: cardinal rows times the cores, core by core."""
    out = {}
    for u, fm in cb.fields.items():
        v = np.ones(1)
        for core, j in zip(fm.cores, fm.mode_order):
            c = cb.coordinates[j]
            row = c.basis().interpolation_matrix([point[c.name]])[0]
            v = np.einsum("r,rns,n->s", v, core, row)
        out[u] = float(v[0])
    return out


def _tt_points(cb):
    """Between nodes, at nodes, at slab breakpoints, at and just inside the ends, mixed."""
    rng = np.random.default_rng(13)
    values = {}
    for c in cb.coordinates:
        lo, hi = c.domain
        nodes = c.basis().nodes
        values[c.name] = [float(rng.uniform(lo, hi)), float(nodes[2]), lo, hi, lo + 1e-15, hi - 1e-15 * (hi - lo),
                          float(nodes[3]) + 1e-13, *c.breakpoints[1:-1]]
    points = []
    for k in range(40):
        points.append({name: v[k % len(v)] if k < 10 else v[int(rng.integers(len(v)))] for name, v in values.items()})
    return points


@pytest.mark.parametrize("order", [(0, 1, 2), (1, 0, 2), (2, 1, 0)], ids=str)
@pytest.mark.parametrize("layout", ["default", "no pair", "vector first"])
def test_tensor_train_point_agrees_with_batch_and_plain_contraction(monkeypatch, order, layout):
    if layout != "default":
        monkeypatch.setattr(point_module, "PAIR_MAX", 0)
    if layout == "vector first":
        monkeypatch.setattr(point_module, "ROW_FIRST_MAX", 0)
    cb = _small_tt_codebook(order)
    stack = cb._tt_stack
    # the first coordinate's window (a slab: 5 nodes, x: 7, an element of y: 2) is below the rank 9
    assert (stack.pair is not None) == (layout == "default")
    if layout == "vector first":
        assert not any(through_table for _, through_table, *_ in stack.tail)
    for p in _tt_points(cb):
        one = cb(**p)
        batch = cb(**{k: np.array([v, 0.5 * sum(c.domain)]) for c, (k, v) in zip(cb.coordinates, p.items())})
        plain = _direct_tt(cb, p)
        assert list(one) == ["u", "w"]
        for u in cb.unknown_names:
            assert isinstance(one[u], np.ndarray) and one[u].shape == () and one[u].dtype == np.float64
            scale = max(1.0, abs(plain[u]))
            assert abs(float(one[u]) - batch[u][0]) <= 1e-13 * scale, (p, u)
            assert abs(float(one[u]) - plain[u]) <= 1e-13 * scale, (p, u)
        # evaluate with fields (the general one-point path) and numpy scalars give the same values
        assert float(cb.evaluate(p, fields=["w"])["w"]) == float(one["w"])
        assert float(cb(**{k: np.float64(v) for k, v in p.items()})["u"]) == float(one["u"])


def test_tensor_train_point_at_nodes_is_the_nodal_value():
    cb = _small_tt_codebook((0, 1, 2))
    nodes = [c.basis().nodes for c in cb.coordinates]
    full = {u: cb.nodal_values(u) for u in cb.unknown_names}
    for index in [(0, 0, 0), (4, 3, 2), (8, 6, 5), (12, 1, 4)]:  # t[4], t[8]: slab breakpoints
        one = cb(**{c.name: float(n[i]) for c, n, i in zip(cb.coordinates, nodes, index)})
        for u in cb.unknown_names:
            assert float(one[u]) == pytest.approx(full[u][index], rel=1e-14, abs=1e-14)


def test_tensor_train_point_errors_and_fallbacks():
    cb = _small_tt_codebook((0, 1, 2))
    with pytest.raises(QueryError, match=r"coordinate 'x': value 2\.5 is outside the domain \[-1, 2\]"):
        cb(t=1.0, x=2.5, y=0.7)
    with pytest.raises(QueryError, match=r"coordinate 't': value nan is outside"):
        cb(t=float("nan"), x=9.0, y=0.7)  # the first bad coordinate in coordinate order, as for arrays
    with pytest.raises(QueryError, match="missing coordinate 'y'"):
        cb(t=1.0, x=0.5)
    with pytest.raises(QueryError, match="unknown coordinate 'z'"):
        cb(t=1.0, x=0.5, y=0.7, z=1.0)
    one = cb(t=1, x=0, y=1)  # Python ints, as floats
    assert float(one["u"]) == float(cb(t=1.0, x=0.0, y=1.0)["u"])
    shaped = cb(t=[[1.0]], x=0.0, y=1.0)  # one point given as an array keeps its shape
    assert shaped["u"].shape == (1, 1) and shaped["u"][0, 0] == pytest.approx(float(one["u"]), rel=1e-13)


def test_one_point_of_a_mixed_codebook():
    """CP modes, a stacked tensor train and one of another core order (outside the stack) together."""
    from pgdcli.codebook.codebook import TT

    tt = _small_tt_codebook((0, 1, 2))
    other = _small_tt_codebook((2, 0, 1)).fields["u"]
    rng = np.random.default_rng(14)
    cp = CPTensor(rng.standard_normal(3), tuple(rng.standard_normal((c.nodes, 3)) for c in tt.coordinates))
    cb = Codebook(tt.coordinates, {"m": cp, "u": tt.fields["u"], "o": other}, name="mixed", report={})
    assert isinstance(cb.fields["o"], TT) and cb._tt_all is None and list(cb._tt_stack.index) == ["u"]
    for p in _tt_points(cb):
        one = cb(**p)
        batch = cb(**{k: np.array([v, v]) for k, v in p.items()})
        assert list(one) == ["m", "u", "o"]
        for u in cb.unknown_names:
            assert one[u].shape == ()
            assert abs(float(one[u]) - batch[u][0]) <= 1e-13 * max(1.0, abs(batch[u][0])), (p, u)
        assert float(cb.evaluate(p, fields=["o", "m"])["m"]) == float(one["m"])


# ----------------------------------------------------------------------------------------------
# Codebook.evaluate_grid: the cartesian product, coordinate by coordinate
# ----------------------------------------------------------------------------------------------
def _mixed_codebook():
    """CP modes, a tensor train in coordinate order and one in another core order."""
    tt = _small_tt_codebook((0, 1, 2))
    other = _small_tt_codebook((2, 0, 1)).fields["u"]
    rng = np.random.default_rng(14)
    cp = CPTensor(rng.standard_normal(3), tuple(rng.standard_normal((c.nodes, 3)) for c in tt.coordinates))
    return Codebook(tt.coordinates, {"m": cp, "u": tt.fields["u"], "o": other, "w": tt.fields["w"]},
                    name="mixed", report={})


def _grid_axes(cb, seed=15):
    """Per coordinate: random values, nodes, slab breakpoints, both ends (unsorted: any order is valid)."""
    rng = np.random.default_rng(seed)
    axes = {}
    for c in cb.coordinates:
        lo, hi = c.domain
        nodes = c.basis().nodes
        axes[c.name] = np.array([*rng.uniform(lo, hi, 4), nodes[1], hi, lo, *c.breakpoints[1:-1]])
    return axes


def _pointwise(cb, axes, fields=None):
    mesh = np.meshgrid(*[axes[c.name] for c in cb.coordinates], indexing="ij")
    return cb.evaluate({c.name: m for c, m in zip(cb.coordinates, mesh)}, fields=fields)


def test_evaluate_grid_matches_pointwise_evaluation_of_the_product():
    cb = _mixed_codebook()
    axes = _grid_axes(cb)
    grid = cb.evaluate_grid(axes)
    flat = _pointwise(cb, axes)
    assert list(grid) == ["m", "u", "o", "w"]
    for u in cb.unknown_names:
        assert grid[u].shape == tuple(axes[c.name].size for c in cb.coordinates)
        scale = max(1.0, float(np.max(np.abs(flat[u]))))
        assert np.max(np.abs(grid[u] - flat[u])) <= 1e-13 * scale, u


@pytest.mark.parametrize("name", ["spring", "relaxation"])
def test_evaluate_grid_of_shipped_cp_codebooks(solved, name):
    """CP (spring), and linear-element coordinates (relaxation), against the point path and the exact solution."""
    from conftest import EXACT

    cb = solved(name).codebook
    rng = np.random.default_rng(16)
    axes = {c.name: np.sort(rng.uniform(*c.domain, 5 + j)) for j, c in enumerate(cb.coordinates)}
    grid = cb.evaluate_grid(axes)
    flat = _pointwise(cb, axes)
    mesh = np.meshgrid(*[axes[c.name] for c in cb.coordinates], indexing="ij")
    exact = EXACT[name]({c.name: m for c, m in zip(cb.coordinates, mesh)})
    for u in cb.unknown_names:
        assert np.max(np.abs(grid[u] - flat[u])) <= 1e-13 * max(1.0, float(np.max(np.abs(flat[u]))))
        assert np.max(np.abs(grid[u] - exact[u])) <= 1e-8


def test_evaluate_grid_at_all_nodes_is_the_nodal_tensor():
    cb = _mixed_codebook()
    grid = cb.evaluate_grid({c.name: c.basis().nodes for c in cb.coordinates})
    for u in cb.unknown_names:
        full = cb.nodal_values(u)
        assert grid[u].shape == full.shape
        assert np.max(np.abs(grid[u] - full)) <= 1e-14 * max(1.0, float(np.max(np.abs(full)))), u


def test_evaluate_grid_shapes_order_and_fields():
    cb = _mixed_codebook()
    axes = {"y": [0.7, 1.1], "x": 0.25, "t": np.linspace(0.0, 3.0, 5)}  # mapping order is irrelevant
    out = cb.evaluate_grid(axes, fields=["w", "m"])
    assert list(out) == ["w", "m"]
    assert out["w"].shape == (5, 1, 2)  # codebook order (t, x, y); a scalar is an axis of length 1
    flat = _pointwise(cb, {k: np.atleast_1d(v) for k, v in axes.items()}, fields=["w", "m"])
    for u in ("w", "m"):
        assert np.max(np.abs(out[u] - flat[u])) <= 1e-13 * max(1.0, float(np.max(np.abs(flat[u]))))
    empty = cb.evaluate_grid({"t": [], "x": [0.0, 1.0], "y": 1.0})
    assert all(v.shape == (0, 2, 1) for v in empty.values())


@pytest.mark.parametrize("axes, pattern", [
    ({"t": [1.0], "x": [0.5]}, r"missing coordinate 'y' \(domain \[0\.5, 1\.5\]\)"),
    ({"t": [1.0], "x": [0.5], "y": [1.0], "z": [0.0]}, r"unknown coordinate 'z'; this codebook has t, x, y"),
    ({"t": [1.0], "x": [0.5, 2.5], "y": [1.0]}, r"coordinate 'x': value 2\.5 is outside the domain \[-1, 2\]"),
    ({"t": [1.0], "x": [[0.5, 1.0]], "y": [1.0]}, r"coordinate 'x': a grid axis must be 1-D, got shape \(1, 2\)"),
    ({"t": [float("nan")], "x": [0.5], "y": [1.0]}, r"coordinate 't': value nan is outside"),
])
def test_evaluate_grid_errors_name_the_coordinate(axes, pattern):
    with pytest.raises(QueryError, match=pattern):
        _mixed_codebook().evaluate_grid(axes)
    with pytest.raises(QueryError, match=r"unknown field 'q'"):
        _mixed_codebook().evaluate_grid({"t": 1.0, "x": 0.5, "y": 1.0}, fields=["q"])
