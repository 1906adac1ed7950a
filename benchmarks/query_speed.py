"""Query speed of pgdcli codebooks, beside scipy's RegularGridInterpolator, in one run.

    python benchmarks/query_speed.py            # full run (a few minutes)
    python benchmarks/query_speed.py --quick    # fewer repetitions (a minute)

Solves the shipped problems (problems/spring.yaml, problems/relaxation.yaml) into a
temporary directory, then measures

- single-point latency of the in-process API, ``codebook(t=..., k=..., ...)`` with
  Python floats, and of scipy's RegularGridInterpolator (RGI) on the equivalent full
  nodal grid (``Codebook.nodal_values``; all unknowns in one RGI, trailing axis);
- batch throughput at 1e5 uniform random points, same two, plus the BLAS/thread
  configurations the batch path chooses between;
- ``pgd query`` as a subprocess: one point (wall time, median over many runs,
  interleaved with ``python -c "import numpy, h5py"``) and 1e5 points from a CSV file.

RGI methods: 'linear' for every codebook, the fast and least accurate interpolant on
the same nodes (the relevant speed baseline), and 'cubic' where every axis has >= 4
nodes (spring). The machine may be shared and noisy: every figure is a median of
repeated blocks, and every comparison is made within this run.

The table (Markdown) is printed and written to benchmarks/results/query_speed.md.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _machine import cell, median_seconds, published  # benchmarks/ is on sys.path when a script runs

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = {"spring": ROOT / "problems" / "spring.yaml", "relaxation": ROOT / "problems" / "relaxation.yaml"}
BATCH = 100_000
TARGET_SINGLE_US = 20.0
TARGET_BATCH = 2e6
TARGET_CLI_RATIO = 1.3


# ----------------------------------------------------------------------------------------------
# timing helpers
# ----------------------------------------------------------------------------------------------
def per_call(func, calls: int, blocks: int) -> float:
    """Median over ``blocks`` of the mean time of one call in a block of ``calls`` calls (seconds)."""
    func()
    times = []
    for _ in range(blocks):
        start = time.perf_counter()
        for _ in range(calls):
            func()
        times.append((time.perf_counter() - start) / calls)
    return statistics.median(times)


once = median_seconds  # median wall time of func() over repeats runs, after one warm-up (seconds)


def interleaved(commands: dict[str, list[str]], runs: int, env: dict, stdin_path=None) -> dict[str, float]:
    """Median wall time (seconds) of each command as a subprocess, the commands run in turn."""
    times = {k: [] for k in commands}
    for i in range(runs + 2):
        for name, argv in commands.items():
            stdin = open(stdin_path, "rb") if stdin_path else subprocess.DEVNULL
            start = time.perf_counter()
            proc = subprocess.run(argv, stdin=stdin, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
            elapsed = time.perf_counter() - start
            if stdin_path:
                stdin.close()
            if proc.returncode != 0:
                raise SystemExit(f"{' '.join(argv)} failed: {proc.stderr.decode().strip()}")
            if i >= 2:  # two warm-up rounds: page cache, bytecode cache
                times[name].append(elapsed)
    return {k: statistics.median(v) for k, v in times.items()}


def fmt_time(seconds: float) -> str:
    if seconds < 1e-3:
        return f"{seconds * 1e6:.1f} us"
    if seconds < 1:
        return f"{seconds * 1e3:.1f} ms"
    return f"{seconds:.2f} s"


def fmt_rate(points_per_s: float) -> str:
    return f"{points_per_s / 1e6:.2f}e6 pts/s"


# ----------------------------------------------------------------------------------------------
# setup
# ----------------------------------------------------------------------------------------------
def solve_codebooks(directory: Path) -> dict[str, Path]:
    import pgdcli

    paths = {}
    for name, spec in PROBLEMS.items():
        start = time.perf_counter()
        result = pgdcli.solve(pgdcli.load_spec(spec))
        if not result.converged:
            raise SystemExit(f"{spec}: {result.message}")
        path = directory / f"{name}.h5"
        result.codebook.save(path)
        ranks = ", ".join(f"{u} {fm.rank}" for u, fm in result.codebook.fields.items())
        print(f"solved {spec.name}: modes {ranks} ({time.perf_counter() - start:.1f} s)", file=sys.stderr)
        paths[name] = path
    return paths


def rgi_for(cb, method: str):
    """scipy RegularGridInterpolator on the full nodal grid; all unknowns on a trailing axis."""
    from scipy.interpolate import RegularGridInterpolator

    grid = [c.basis().nodes for c in cb.coordinates]
    values = np.stack([cb.nodal_values(u) for u in cb.unknown_names], axis=-1)
    rgi = RegularGridInterpolator(grid, values, method=method)
    if method == "linear":  # the same values at the nodes: the grid is the codebook's
        index = tuple(n.size // 2 for n in grid)
        at = {c.name: float(g[i]) for c, g, i in zip(cb.coordinates, grid, index)}
        ours = cb(**at)
        theirs = rgi(np.array([[at[c.name] for c in cb.coordinates]]))[0]
        assert np.allclose([float(ours[u]) for u in cb.unknown_names], theirs, rtol=1e-12, atol=1e-12)
    return rgi


def random_points(cb, n: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {c.name: rng.uniform(c.domain[0], c.domain[1], n) for c in cb.coordinates}


def midpoint_args(cb) -> dict[str, float]:
    """A point off the nodes (a fixed fraction of each domain)."""
    return {c.name: c.domain[0] + 0.3719 * (c.domain[1] - c.domain[0]) for c in cb.coordinates}


def pgd_executable() -> list[str]:
    exe = shutil.which("pgd", path=str(Path(sys.executable).parent)) or shutil.which("pgd")
    if exe is None:
        raise SystemExit("the pgd console script is not installed (pip install -e .)")
    return [exe]


def cli_env(bytecode_cache: str | None) -> dict:
    env = dict(os.environ)
    if bytecode_cache is not None:  # as an installed package: compiled modules cached
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = bytecode_cache
    return env


# ----------------------------------------------------------------------------------------------
# measurements
# ----------------------------------------------------------------------------------------------
def measure_in_process(name: str, path: Path, rows: list, quick: bool) -> None:
    import pgdcli.codebook.threads as threads_module
    from pgdcli.codebook.codebook import Codebook
    from threadpoolctl import threadpool_limits

    cb = Codebook.load(path)
    label = f"{name} ({len(cb.coordinates)} coords, modes {'+'.join(str(fm.rank) for fm in cb.fields.values())})"
    blocks = 9 if quick else 25
    point = midpoint_args(cb)
    xrow = np.array([[point[c.name] for c in cb.coordinates]])
    methods = ["linear"] + (["cubic"] if all(c.nodes >= 4 for c in cb.coordinates) else [])
    rgis = {m: rgi_for(cb, m) for m in methods}

    # single point
    ours = per_call(lambda: cb(**point), 2000, blocks)
    with threadpool_limits(1):
        ours_blas1 = per_call(lambda: cb(**point), 2000, blocks)
    for i, (m, rgi) in enumerate(rgis.items()):
        theirs = per_call(lambda: rgi(xrow), 200, blocks)
        rows.append((label, "single point, in-process", fmt_time(ours), f"RGI {m}: {fmt_time(theirs)}",
                     f"{theirs / ours:.1f}x", f"<= {TARGET_SINGLE_US:g} us" if i == 0 else "",
                     ours * 1e6 <= TARGET_SINGLE_US if i == 0 else None))
    rows.append((label, "  single point, BLAS limited to 1 thread", fmt_time(ours_blas1), "", "", "", None))
    before = per_call(lambda: evaluation_before(cb, point), 500, blocks)
    rows.append((label, "  single point, as pgdcli 0.1.0 evaluated it", fmt_time(before), "pgdcli (above)",
                 f"{ours / before:.2f}x", "", None))

    # batch: the chosen policy, then the alternatives it was chosen from
    points = random_points(cb, BATCH, seed=1)
    xmat = np.column_stack([points[c.name] for c in cb.coordinates])
    repeats = 7 if quick else 15
    capacity = parallel_capacity()
    policy = once(lambda: cb.evaluate(points), repeats)
    capacity = min(capacity, parallel_capacity())
    for i, (m, rgi) in enumerate(rgis.items()):
        theirs = once(lambda: rgi(xmat), repeats)
        rows.append((label, f"batch of 1e5 random points, in-process (2 threads did {capacity:.1f}x)",
                     fmt_rate(BATCH / policy),
                     f"RGI {m}: {fmt_rate(BATCH / theirs)}", f"{theirs / policy:.2f}x",
                     ">= 2e6 pts/s" if i == 0 else "", BATCH / policy >= TARGET_BATCH if i == 0 else None))
    saved = (threads_module.MAX_THREADS, threads_module.BLAS_LIMIT_MIN_POINTS)
    try:
        threads_module.MAX_THREADS = 1
        serial = once(lambda: cb.evaluate(points), repeats)
        threads_module.BLAS_LIMIT_MIN_POINTS = 1 << 62
        serial_blas = once(lambda: cb.evaluate(points), repeats)
    finally:
        threads_module.MAX_THREADS, threads_module.BLAS_LIMIT_MIN_POINTS = saved
    unchunked = once(lambda: unchunked_evaluation(cb, points), max(3, repeats // 3))
    with threadpool_limits(1):
        unchunked_1 = once(lambda: unchunked_evaluation(cb, points), max(3, repeats // 3))
    threads = f"{threads_module.available_threads()} threads"
    for what, seconds in [
        (f"  batch, chunks on 1 thread (policy: {threads}), BLAS 1 thread", serial),
        ("  batch, chunks on 1 thread, BLAS default threads", serial_blas),
        ("  batch, unchunked (as pgdcli 0.1.0), BLAS default threads", unchunked),
        ("  batch, unchunked (as pgdcli 0.1.0), BLAS 1 thread", unchunked_1),
    ]:
        rows.append((label, what, fmt_rate(BATCH / seconds), "policy (above)", f"{policy / seconds:.2f}x",
                     "", None))


def evaluation_before(cb, coordinates):
    """Codebook.evaluate as in pgdcli 0.1.0: broadcast, check, then the unchunked algorithm."""
    from pgdcli.codebook.domain import clip_to_domain

    for key in coordinates:
        if key not in cb.coordinate_names:
            raise KeyError(key)
    arrays = np.broadcast_arrays(*[np.asarray(coordinates[n], dtype=float) for n in cb.coordinate_names])
    shape = arrays[0].shape
    flat = {c.name: clip_to_domain(c, a.reshape(-1)) for c, a in zip(cb.coordinates, arrays)}
    return {u: v.reshape(shape) for u, v in unchunked_evaluation(cb, flat).items()}


def unchunked_evaluation(cb, points):
    """The algorithm before chunking: (points, nodes) @ (nodes, rank) per coordinate over all points."""
    product = None
    for c, basis, modes in zip(cb.coordinates, cb._bases, cb._stacked):
        vals = basis.interpolation_matrix(points[c.name]) @ modes
        product = vals if product is None else product * vals
    return {u: product[:, cb._slices[u]] @ cb.fields[u].weights for u in cb.unknown_names}


def measure_cli(name: str, path: Path, rows: list, quick: bool, workdir: Path) -> None:
    from pgdcli.codebook.codebook import Codebook

    cb = Codebook.load(path)
    label = f"{name} ({len(cb.coordinates)} coords)"
    point = midpoint_args(cb)
    query = pgd_executable() + ["query", str(path)] + [a for c in cb.coordinates for a in (f"--{c.name}", repr(point[c.name]))]
    base = [sys.executable, "-c", "import numpy, h5py"]
    runs = 15 if quick else 41
    cache = tempfile.mkdtemp(prefix="pycache-", dir=workdir)
    configs = [("bytecode cached", cli_env(cache))]
    if os.environ.get("PYTHONDONTWRITEBYTECODE"):  # as this environment runs it: every module compiled
        configs.insert(0, ("no bytecode cache, as this environment", cli_env(None)))
    # the same query through the click command (what `pgd query` ran before the lean path)
    through_click = [sys.executable, "-c", "import sys; from pgdcli.cli.main import cli; "
                     "cli.main(sys.argv[1:], prog_name='pgd')"] + query[1:]
    for env_label, env in configs:
        medians = interleaved({"base": base, "pgd": query, "click": through_click}, runs, env)
        ratio = medians["pgd"] / medians["base"]
        rows.append((label, f"pgd query, one point, wall, {env_label}", fmt_time(medians["pgd"]),
                     f"python -c 'import numpy, h5py': {fmt_time(medians['base'])}", f"{ratio:.2f}x",
                     f"<= {TARGET_CLI_RATIO:g}x", ratio <= TARGET_CLI_RATIO))
        rows.append((label, f"  same query through click (before the lean path), {env_label}",
                     fmt_time(medians["click"]), "import numpy, h5py (above)",
                     f"{medians['click'] / medians['base']:.2f}x", "", None))
    # a batch through the CLI: CSV in, one line per point out
    points = random_points(cb, BATCH, seed=2)
    csv = workdir / f"{name}-points.csv"
    data = np.column_stack([points[c.name] for c in cb.coordinates])
    np.savetxt(csv, data, delimiter=",", header=",".join(c.name for c in cb.coordinates), comments="", fmt="%.17g")
    batch = interleaved({"pgd": pgd_executable() + ["query", str(path), "--points", str(csv)]},
                        3 if quick else 7, cli_env(cache))
    rows.append((label, "pgd query --points, 1e5 CSV rows in, 1e5 lines out, wall",
                 fmt_rate(BATCH / batch["pgd"]), "", "", "", None))


# ----------------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------------
def print_table(rows: list) -> None:
    header = ("codebook", "measure", "pgdcli", "reference, same run", "ratio", "target", "met")
    cells = [header] + [tuple("" if v is None else ("yes" if v is True else "NO" if v is False else cell(v))
                              for v in row) for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    line = lambda r: "| " + " | ".join(v.ljust(w) for v, w in zip(r, widths)) + " |"
    print(line(cells[0]))
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in cells[1:]:
        print(line(r))


def parallel_capacity() -> float:
    """How much work 2 threads get done, relative to 1, on GIL-free BLAS work right now.

    2.0 on 2 idle cores; about 1.0 when other processes keep one core busy (then no
    threading can help the batch path).
    """
    from threadpoolctl import threadpool_limits
    import threading

    a = np.random.default_rng(0).standard_normal((300, 300))

    def work():
        for _ in range(40):
            a @ a

    with threadpool_limits(1):
        work()
        start = time.perf_counter()
        work()
        one = time.perf_counter() - start
        threads = [threading.Thread(target=work) for _ in range(2)]
        start = time.perf_counter()
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        two = time.perf_counter() - start
    return 2 * one / two


def describe_machine() -> str:
    """What the header of :func:`_machine.published` does not say: free cores now, the environment."""
    return (f"2 threads run {parallel_capacity():.1f}x one thread's work now; "
            f"PYTHONDONTWRITEBYTECODE={os.environ.get('PYTHONDONTWRITEBYTECODE', '(unset)')}, "
            f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', '(unset)')}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions")
    parser.add_argument("--no-cli", action="store_true", help="in-process measurements only")
    parser.add_argument("--codebooks", nargs="+", choices=sorted(PROBLEMS), default=list(PROBLEMS))
    args = parser.parse_args(argv)
    rows: list = []
    with tempfile.TemporaryDirectory(prefix="pgdcli-bench-") as tmp:
        work = Path(tmp)
        paths = solve_codebooks(work)
        for name in args.codebooks:
            measure_in_process(name, paths[name], rows, args.quick)
        if not args.no_cli:
            for name in args.codebooks:
                measure_cli(name, paths[name], rows, args.quick, work)
    print(f"Threads and environment: {describe_machine()}\n")
    print_table(rows)
    print("\nratio: latency = reference / pgdcli, throughput = pgdcli / reference (above 1: pgdcli faster); "
          "pgd query = its wall time / that of python -c 'import numpy, h5py'.")
    missed = [r for r in rows if r[6] is False]
    print(f"\n{len([r for r in rows if r[6] is True])} targets met, {len(missed)} missed"
          + "".join(f"\n\n- missed: {r[0]}: {r[1]}: {r[2]} (target {r[5]})" for r in missed))


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt), published(__file__, "Query speed: codebooks beside RegularGridInterpolator"):
        main()
