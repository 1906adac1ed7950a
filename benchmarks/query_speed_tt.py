"""Query speed of tensor-train codebooks (nonlinear problems), beside RegularGridInterpolator.

Solves problems/coupled.yaml, problems/logistic.yaml and problems/rigid_body.yaml into a
temporary directory, then measures in one process, per codebook:

- single point, in-process: ``codebook(t=..., ...)`` with Python floats; median of 15 blocks
  of 200 calls: one point repeated (since the tail cache of ``pgdcli.codebook.point``, only the
  first core(s) are contracted again: a best case), 200 random points (every core contracted:
  the target's row), and a time series of 200 random times at one random parameter point;
- batch: ``codebook.evaluate`` at 1e5 uniform random points, median of 5 runs, with the batch
  policy (one BLAS thread, up to 2 threads of our own: pgdcli.codebook.threads) and on one thread;
  beside it, in the same run, the plain row-wise algorithm (per block of 2048 points the
  row-wise Khatri-Rao product of the running contraction and the cardinal rows times each
  unfolded core, unknown by unknown, all cores dense: ``rowwise_batch`` below);
- the error gate's shape: 200 random parameter points x the time nodes and midpoints,
  ``Codebook.evaluate_series`` beside ``Codebook.evaluate`` on the broadcast points; for the rigid
  body also the single point's memory floor (its cores read once by one gemv per core);
- ``pgd query --points`` with the same 1e5 points in a CSV file (wall time, one run: CSV parsing
  and printing included);
- grid: ``codebook.evaluate_grid`` on a cartesian product of random values per coordinate
  (~1e6 points; 8 x 5^6 = 125,000 for the rigid body), median of 3, beside ``codebook.evaluate``
  and the reference at the same points, flattened;
- the same with scipy's ``RegularGridInterpolator`` (method 'linear', the cheapest
  interpolant) on the codebook's own full nodal grid (``Codebook.nodal_values``, all unknowns
  on a trailing axis), built in the same run; for the 7-D rigid body the grid has 26 x 8^6
  nodes x 6 unknowns (~330 MB).

Prints a table with ratios (latency: reference / pgdcli; throughput: pgdcli / reference).
Targets: batch >= RGI linear for coupled and the rigid body; single point <= 20 us (coupled),
<= 50 us (rigid body). The machine is shared and noisy: medians, same process. The table is
printed and written to benchmarks/results/query_speed_tt.md.

    python benchmarks/query_speed_tt.py [--quick] [--before OLD/pgdcli]
    # --quick: coupled and logistic only; --before: an earlier package side by side
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


class _PointCall:
    """``call()`` evaluates an interpolator at one fixed point (the reference's single-point path)."""

    def __init__(self, interpolator, point):
        self.interpolator, self.point = interpolator, point

    def __call__(self):
        return self.interpolator(self.point)


def _single(cb, args: dict) -> float:
    for _ in range(200):
        cb(**args)
    blocks = []
    for _ in range(15):
        t0 = time.perf_counter()
        for _ in range(200):
            cb(**args)
        blocks.append((time.perf_counter() - t0) / 200)
    return statistics.median(blocks)


def _each(fn, calls: list) -> float:
    """Median seconds per call of ``fn(**kwargs)`` over ``calls`` (a list of keyword dicts): 15 blocks."""
    for kwargs in calls:
        fn(**kwargs)
    blocks = []
    for _ in range(15):
        t0 = time.perf_counter()
        for kwargs in calls:
            fn(**kwargs)
        blocks.append((time.perf_counter() - t0) / len(calls))
    return statistics.median(blocks)


def _batch(fn, points, repeats: int = 5) -> float:
    fn(points)
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(points)
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs)


def rowwise_batch(cb, points: dict) -> dict:
    """The plain row-wise tensor-train batch (a baseline for ``Codebook.evaluate``), same thread policy."""
    import pgdcli.codebook.threads as threads_module

    flat = [np.clip(points[c.name], *c.domain) for c in cb.coordinates]
    size = flat[0].size
    values = {u: np.empty(size) for u in cb.unknown_names}

    def contract(fm, mats):
        v = None
        for core, j in zip(fm.cores, fm.mode_order):
            r0, n, r1 = core.shape
            if v is None:
                v = mats[j] @ core[0]
            else:
                kr = (v[:, :, None] * mats[j][:, None, :]).reshape(v.shape[0], r0 * n)
                v = kr @ core.reshape(r0 * n, r1)
        return v[:, 0]

    def run(bounds):
        for lo, hi in bounds:
            mats = [b.interpolation_matrix(x[lo:hi]) for b, x in zip(cb._bases, flat)]
            for u in cb.unknown_names:
                values[u][lo:hi] = contract(cb.fields[u], mats)

    threads_module.run_chunks(run, threads_module.chunk_bounds(size, 2048))
    return values


def _series_rows(cb, rng, label: str) -> list:
    """The error gate's shape: S parameter points x T times (nodes and midpoints), ``evaluate_series``
    against ``evaluate`` on the broadcast points; medians of 7, same process."""
    from pgdcli.checks.check import nodes_and_midpoints

    time_name = cb.coordinates[0].name
    times, _ = nodes_and_midpoints(cb, time_name)
    points = {c.name: rng.uniform(*c.domain, 200) for c in cb.coordinates[1:]}
    broadcast = {time_name: times[None, :]} | {n: v[:, None] for n, v in points.items()}
    flat = _batch(cb.evaluate, broadcast, repeats=7)
    series = _batch(lambda p: cb.evaluate_series(p, {time_name: times}), points, repeats=7)
    diff = max(float(np.max(np.abs(cb.evaluate_series(points, {time_name: times})[u] - cb.evaluate(broadcast)[u])))
               for u in cb.unknown_names)
    return [(label, f"check shape: 200 samples x {times.size} times, evaluate_series", f"{series * 1e3:.2f} ms",
             f"evaluate, broadcast points: {flat * 1e3:.2f} ms", f"{flat / series:.0f}x", "", None),
            (label, "  max |series - evaluate|", f"{diff:.1e}", "", "", "", None)]


def _stream_floor(cb, rng) -> float:
    """Seconds to read every core once as one point does (the unknowns' cores zero-padded to common
    ranks, one batched gemv per core, as ``codebook.point.TTStack``): the single point's memory floor."""
    fields = list(cb.fields.values())
    stacks = []
    for k in range(len(fields[0].cores)):
        r0 = max(f.cores[k].shape[0] for f in fields)
        n = fields[0].cores[k].shape[1]
        r1 = max(f.cores[k].shape[2] for f in fields)
        stacks.append((rng.standard_normal((len(fields), 1, r1)), rng.standard_normal((len(fields), r1, r0 * n))))

    def read():
        for _ in range(100):
            for v, table in stacks:
                np.matmul(v, table)

    return _batch(lambda _: read(), None, repeats=15) / 100


def cli_points(path: Path, pts: dict, coords, tmp: str) -> float:
    """Wall time of ``pgd query PATH --points CSV`` on the points (one run, output discarded)."""
    csv = Path(tmp) / f"{path.stem}-points.csv"
    np.savetxt(csv, np.column_stack([pts[c.name] for c in coords]), delimiter=",",
               header=",".join(c.name for c in coords), comments="", fmt="%.17g")
    exe = shutil.which("pgd", path=str(Path(sys.executable).parent)) or shutil.which("pgd")
    t0 = time.perf_counter()
    subprocess.run([exe, "query", str(path), "--points", str(csv)], check=True, stdout=subprocess.DEVNULL,
                   env=dict(os.environ))
    return time.perf_counter() - t0


def axes_of(cb, rng, name: str) -> dict:
    """The grid row's axes: random sorted values, more along time."""
    sizes = {"coupled": (64, 25), "logistic": (100, 100), "rigid_body": (8, 5)}[name]
    return {c.name: np.sort(rng.uniform(*c.domain, sizes[0] if c.role == "time" else sizes[1]))
            for c in cb.coordinates}


def _before_rows(folder: Path, path: Path, label: str, spread: list, series: list, axes: dict, batch: dict) -> list:
    """Single points (random, time series), the batch (medians of 5) and evaluate_grid of this version and the
    one in ``folder``, interleaved run by run (benchmarks/layout_speed.py), medians of 9; per call in us, grid in ms."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from layout_speed import alternate, load_before

    import pgdcli

    before = sys.modules.get("pgdcli_before") or load_before(folder)
    books = {"this": pgdcli.Codebook.load(path), "before": before.Codebook.load(path)}
    rows = []
    for what, calls in (("random points", spread), ("time series", series)):
        t = alternate({k: (lambda b=b: [b(**p) for p in calls]) for k, b in books.items()}, 9)
        rows.append((label, f"  {what}: this vs before (interleaved)", f"{t['this'] / len(calls) * 1e6:.1f} us",
                     f"before: {t['before'] / len(calls) * 1e6:.1f} us", f"{t['before'] / t['this']:.2f}x", "", None))
    t = alternate({k: (lambda b=b: b.evaluate(batch)) for k, b in books.items()}, 5)
    size = next(iter(batch.values())).size
    rows.append((label, f"  batch of {size:.0e} random points: this vs before (interleaved)",
                 f"{size / t['this']:.3g} pts/s", f"before: {size / t['before']:.3g} pts/s",
                 f"{t['before'] / t['this']:.2f}x", "", None))
    t = alternate({k: (lambda b=b: b.evaluate_grid(axes)) for k, b in books.items()}, 9)
    rows.append((label, "  evaluate_grid: this vs before (interleaved)", f"{t['this'] * 1e3:.1f} ms",
                 f"before: {t['before'] * 1e3:.1f} ms", f"{t['before'] / t['this']:.2f}x", "", None))
    diff = max(float(np.max(np.abs(books["this"].evaluate_grid(axes)[u] - books["before"].evaluate_grid(axes)[u])))
               for u in books["this"].unknown_names)
    rows.append((label, "  max |this - before| on the grid", f"{diff:.1e}", "", "", "", None))
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coupled and logistic only")
    parser.add_argument("--before", type=Path, help="package folder of an earlier version: its single points and "
                        "grids side by side (interleaved) with this one's")
    options = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    import pgdcli
    import pgdcli.codebook.threads as threads_module
    from scipy.interpolate import RegularGridInterpolator

    names = ["coupled", "logistic"] + ([] if options.quick else ["rigid_body"])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            result = pgdcli.solve(pgdcli.load_spec(ROOT / "problems" / f"{name}.yaml"))
            path = result.codebook.save(Path(tmp) / f"{name}.h5")
            cb = pgdcli.Codebook.load(path)
            coords = cb.coordinates
            ranks = max(max(f.ranks) for f in cb.fields.values())
            label = f"{name} (TT, {len(coords)} coords, max rank {ranks})"
            mid = {c.name: float(np.mean(c.domain)) + 0.0123 * (c.domain[1] - c.domain[0]) for c in coords}
            rng = np.random.default_rng(0)
            n = 100_000
            pts = {c.name: rng.uniform(*c.domain, n) for c in coords}
            grid = RegularGridInterpolator([c.basis().nodes for c in coords],
                                           np.stack([cb.nodal_values(u) for u in cb.unknown_names], axis=-1),
                                           method="linear")
            single = _single(cb, mid)
            point = np.array([[mid[c.name] for c in coords]])
            ref_single = _single(_PointCall(grid, point), {})
            # 200 random points (no two share a coordinate value: every query contracts every core), and a
            # time series of 200 random times at one random parameter point (the tail cache of codebook.point)
            spread = [{c.name: float(rng.uniform(*c.domain)) for c in coords} for _ in range(200)]
            fixed = dict(spread[0])
            series = [{**fixed, coords[0].name: float(t)} for t in rng.uniform(*coords[0].domain, 200)]
            random_one = _each(cb, spread)
            ref_random = _each(lambda **p: grid(np.array([[p[c.name] for c in coords]])), spread)
            series_one = _each(cb, series)
            if options.before is not None:
                rows.extend(_before_rows(options.before, path, label, spread, series, axes_of(cb, rng, name), pts))
            stack = np.column_stack([pts[c.name] for c in coords])
            batch = _batch(cb.evaluate, pts)
            ref_batch = _batch(grid, stack)
            rowwise = _batch(lambda p: rowwise_batch(cb, p), pts)
            saved = threads_module.MAX_THREADS
            threads_module.MAX_THREADS = 1
            try:
                batch1 = _batch(cb.evaluate, pts)
            finally:
                threads_module.MAX_THREADS = saved
            target_us = {"coupled": 20, "rigid_body": 50}.get(name)
            rows.append((label, "single point, in-process, same point repeated", f"{single * 1e6:.1f} us",
                         f"RGI linear: {ref_single * 1e6:.1f} us", f"{ref_single / single:.2f}x", "", None))
            rows.append((label, "single point, 200 random points", f"{random_one * 1e6:.1f} us",
                         f"RGI linear: {ref_random * 1e6:.1f} us", f"{ref_random / random_one:.2f}x",
                         f"<= {target_us} us" if target_us else "",
                         random_one * 1e6 <= target_us if target_us else None))
            rows.append((label, "  time series: 200 random times, fixed parameters", f"{series_one * 1e6:.1f} us",
                         f"random points: {random_one * 1e6:.1f} us", f"{random_one / series_one:.1f}x", "", None))
            targeted = name in ("coupled", "rigid_body")
            rows.append((label, "batch of 1e5 random points (policy: BLAS 1 thread, our threads)",
                         f"{n / batch:.3g} pts/s", f"RGI linear: {n / ref_batch:.3g} pts/s", f"{ref_batch / batch:.2f}x",
                         ">= RGI" if targeted else "", ref_batch >= batch if targeted else None))
            rows.append((label, "  batch, one thread", f"{n / batch1:.3g} pts/s",
                         f"RGI linear: {n / ref_batch:.3g} pts/s", f"{ref_batch / batch1:.2f}x", "", None))
            rows.append((label, "  batch, plain row-wise algorithm (same policy)", f"{n / rowwise:.3g} pts/s",
                         "pgdcli (policy, above)", f"{rowwise / batch:.2f}x", "", None))
            check = rowwise_batch(cb, pts)
            ours = cb.evaluate(pts)
            diff = max(float(np.max(np.abs(ours[u] - check[u]))) for u in cb.unknown_names)
            rows.append((label, "  max |pgdcli - row-wise| over the batch", f"{diff:.1e}", "", "", "", None))
            rows.extend(_series_rows(cb, rng, label))
            if name == "rigid_body":
                floor = _stream_floor(cb, rng)
                rows.append((label, "  single point: its cores read once by one batched gemv per core (no weights, "
                             "no Python between)", f"{floor * 1e6:.1f} us", f"random points: {random_one * 1e6:.1f} us",
                             f"{floor / random_one:.2f}", "", None))
            wall = cli_points(path, pts, coords, tmp)
            rows.append((label, "pgd query --points, 1e5 CSV rows, wall (one run)", f"{n / wall:.3g} pts/s",
                         "", "", "", None))
            axes = axes_of(cb, rng, name)
            mesh = np.meshgrid(*[axes[c.name] for c in coords], indexing="ij")
            flat = {c.name: m.reshape(-1) for c, m in zip(coords, mesh)}
            m = mesh[0].size
            on_grid = _batch(cb.evaluate_grid, axes, repeats=3)
            on_points = _batch(cb.evaluate, flat, repeats=3)
            ref_grid = _batch(grid, np.column_stack([flat[c.name] for c in coords]), repeats=3)
            shape = "x".join(str(axes[c.name].size) for c in coords)
            rows.append((label, f"grid {shape} = {m:.3g} points: evaluate_grid", f"{m / on_grid:.3g} pts/s",
                         f"evaluate, same points: {m / on_points:.3g} pts/s", f"{on_points / on_grid:.0f}x", "", None))
            rows.append((label, "  (same grid)", f"{m / on_grid:.3g} pts/s",
                         f"RGI linear, same points: {m / ref_grid:.3g} pts/s", f"{ref_grid / on_grid:.0f}x", "", None))
    header = ("codebook", "measure", "pgdcli", "reference, same run", "ratio", "target", "met")
    from _machine import cell

    cells = [header] + [tuple("" if v is None else ("yes" if v is True else "NO" if v is False else cell(v))
                              for v in r) for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    for i, r in enumerate(cells):
        print("| " + " | ".join(v.ljust(w) for v, w in zip(r, widths)) + " |")
        if i == 0:
            print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    print("\nratio: latency = reference / pgdcli, throughput = pgdcli / reference (above 1: pgdcli faster)")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _machine import published

    with published(__file__, "Query speed: tensor-train codebooks beside RegularGridInterpolator"):
        main()
