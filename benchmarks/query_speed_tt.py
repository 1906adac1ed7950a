"""Query speed of tensor-train codebooks (nonlinear problems), beside RegularGridInterpolator.

Solves problems/coupled.yaml, problems/logistic.yaml and problems/rigid_body.yaml into a
temporary directory, then measures in one process, per codebook:

- single point, in-process: ``codebook(t=..., ...)`` with Python floats; median of 15 blocks
  of 200 calls;
- batch: ``codebook.evaluate`` at 1e5 uniform random points, median of 5 runs;
- the same with scipy's ``RegularGridInterpolator`` (method 'linear', the cheapest
  interpolant) on the codebook's own full nodal grid (``Codebook.nodal_values``, all unknowns
  on a trailing axis), built in the same run; for the 7-D rigid body the grid has 26 x 8^6
  nodes x 6 unknowns (~330 MB).

Prints a table with ratios (latency: reference / pgdcli; throughput: pgdcli / reference).
The machine is shared and noisy: medians, same process.

    python benchmarks/query_speed_tt.py [--quick]   # --quick: coupled and logistic only
"""

from __future__ import annotations

import argparse
import statistics
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


def _batch(fn, points) -> float:
    fn(points)
    runs = []
    for _ in range(5):
        t0 = time.perf_counter()
        fn(points)
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coupled and logistic only")
    options = parser.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    import pgdcli
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
            stack = np.column_stack([pts[c.name] for c in coords])
            batch = _batch(cb.evaluate, pts)
            ref_batch = _batch(grid, stack)
            rows.append((label, "single point, in-process", f"{single * 1e6:.1f} us",
                         f"RGI linear: {ref_single * 1e6:.1f} us", f"{ref_single / single:.2f}x"))
            rows.append((label, "batch of 1e5 random points", f"{n / batch:.3g} pts/s",
                         f"RGI linear: {n / ref_batch:.3g} pts/s", f"{ref_batch / batch:.2f}x"))
    widths = [max(len(str(r[i])) for r in rows + [("codebook", "measure", "pgdcli", "reference", "ratio")])
              for i in range(5)]
    header = ("codebook", "measure", "pgdcli", "reference, same run", "ratio")
    print("| " + " | ".join(h.ljust(w) for h, w in zip(header, widths)) + " |")
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows:
        print("| " + " | ".join(str(v).ljust(w) for v, w in zip(r, widths)) + " |")
    print("ratio: latency = reference / pgdcli, throughput = pgdcli / reference (above 1: pgdcli faster)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
