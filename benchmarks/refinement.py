"""The automatic resolution's rounds: how much of a build the rounds before the last one cost.

For each problem, builds the codebook (``pgdcli.solve``, the error gate included) in a fresh
process and records, from the progress events, every round of the automatic resolution (one set
of nodes: its solves, tighter ones included, and their error gates; a method taking over starts a
new one): the nodes per coordinate, the time and the gate's part of it. The table gives the
rounds, the build time, the final round's time and their ratio (1.0: the first nodes were the
last), the largest Chebyshev tail of the codebook over the tolerance per automatic coordinate
(far below 1: more nodes than the tolerance asks for) and the error the gate measured. The first
round's time includes what a first solve in a process compiles and caches.

With ``--baseline REV`` every problem is also built by the source tree of git revision ``REV``
(``git archive``) in the same run, the two builds interleaved, and the table compares them. Builds
of a few seconds are repeated (interleaved) and the median one is shown.

    python benchmarks/refinement.py [--problems hotplate docs/examples/enzyme.yaml ...] [--baseline main]
                                    [--variant NAME]

The table is printed and written to benchmarks/results/refinement.md (refinement-NAME.md with
``--variant``: a table of other problems, such as the graded elements' docs/examples/vdp_start.yaml
and slow_decay.yaml).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from _machine import published  # benchmarks/ is on sys.path when a script runs

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ("hotplate", "heat2d", "moving_source", "suspension", "drag", "pendulum", "robertson",
            "docs/examples/enzyme.yaml")

#: Builds faster than this (seconds) are repeated, interleaved, and the median build is shown.
QUICK = 5.0
REPEATS = 5

#: Run in a fresh process with the source tree first on sys.path: one build, its rounds as JSON.
_BUILD = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
import pgdcli
from pgdcli.progress import PhaseStarted

events = []
def callback(event):
    if isinstance(event, PhaseStarted):
        events.append((time.perf_counter(), event.what, event.text))

problem = pgdcli.load_spec(sys.argv[2])
start = time.perf_counter()
result = pgdcli.solve(problem, callback=callback)
end = time.perf_counter()
rep = result.codebook.report
names = [c.name for c in result.codebook.coordinates]
tails = np.asarray(rep.get("resolution", np.full((1, len(names)), np.nan)), dtype=float)
rounds = np.asarray(rep.get("resolution_rounds", np.zeros((0, len(names) + 1))), dtype=float)
print(json.dumps({
    "start": start, "end": end, "events": events, "names": names,
    "auto": [n for n in str(rep.get("resolution_auto", "")).split(",") if n],
    "rounds": rounds.tolist(), "tails": np.nanmax(tails, axis=0).tolist(),
    "tolerance": float(problem.solver.tolerance), "ratio": float(rep.get("check_ratio", float("nan"))),
    "accurate": int(rep.get("accurate", -1)), "gate": float(rep.get("gate_time", 0.0)),
    "method": str(rep.get("method", "")),
}))
"""


def spec_path(name: str) -> Path:
    """``problems/<name>.yaml``, or a spec's path relative to the repository root."""
    return ROOT / name if name.endswith(".yaml") else ROOT / "problems" / f"{name}.yaml"


def build(source: Path, name: str) -> dict:
    """One build of the spec ``name`` (:func:`spec_path`) by the package in ``source``, in a fresh process."""
    out = subprocess.run([sys.executable, "-c", _BUILD, str(source), str(spec_path(name))],
                         capture_output=True, text=True)
    if out.returncode != 0:
        sys.stderr.write(out.stderr)
        raise SystemExit(f"the build of {name} by {source} failed")
    return json.loads(out.stdout.splitlines()[-1])


def rounds(run: dict) -> list[tuple[float, float]]:
    """Per round, (seconds, gate seconds): a round ends where the next set of nodes starts."""
    marks = [run["start"]] + [t for t, what, text in run["events"]
                              if what == "refine" and (text.startswith("more nodes") or "runs instead" in text)]
    marks.append(run["end"])
    out = []
    for a, b in zip(marks[:-1], marks[1:]):
        gate, inside = 0.0, [e for e in run["events"] if a <= e[0] < b] + [(b, "end", "")]
        for (t0, what, _), (t1, _, _) in zip(inside[:-1], inside[1:]):
            gate += (t1 - t0) if what == "check" else 0.0
        out.append((b - a, gate))
    return out


def nodes_text(run: dict) -> str:
    """The automatic coordinates' nodes per round: ``x 17>33, t 33>65``."""
    idx = [run["names"].index(n) for n in run["auto"]]
    cols = [[int(r[i]) for r in run["rounds"]] for i in idx]
    return ", ".join(f"{n} " + ">".join(str(v) for v in _squeeze(col)) for n, col in zip(run["auto"], cols)) or "given"


def _squeeze(col: list[int]) -> list[int]:
    return [v for i, v in enumerate(col) if i == 0 or v != col[i - 1]]


def tails_text(run: dict) -> str:
    """The largest Chebyshev tail over the tolerance per automatic coordinate (the codebook's)."""
    vals = [(n, run["tails"][run["names"].index(n)] / run["tolerance"]) for n in run["auto"]]
    return ", ".join(f"{n} {v:.0e}" for n, v in vals if v == v) or "-"


def seconds(run: dict) -> float:
    return run["end"] - run["start"]


def summary(run: dict, of: int = 1) -> list[str]:
    """The table's cells of one build (the median of ``of``)."""
    per = rounds(run)
    total, final = seconds(run), per[-1][0]
    median = f", median of {of}" if of > 1 else ""
    return [str(len(run["rounds"]) or 1), nodes_text(run), " + ".join(f"{t:.1f} ({g:.1f})" for t, g in per),
            f"{total:.1f} s (gate {run['gate']:.0f} s{median})", f"{final:.1f} s", f"{total / final:.2f}", tails_text(run),
            f"{run['ratio']:.2g}" + ("" if run["accurate"] == 1 else " (not within)")]


def baseline_tree(rev: str, into: Path) -> Path:
    """The source tree of git revision ``rev`` (its pgdcli package) under ``into``."""
    archive = into / "src.tar"
    subprocess.run(["git", "-C", str(ROOT), "archive", "-o", str(archive), rev, "pgdcli"], check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(into, filter="data")
    return into


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", nargs="+", default=list(PROBLEMS))
    parser.add_argument("--baseline", metavar="REV", help="also build with the pgdcli of this git revision")
    parser.add_argument("--variant", metavar="NAME", help="write the table to results/refinement-NAME.md")
    options = parser.parse_args()
    header = ["problem", "build", "rounds", "nodes per round", "seconds per round (gate)", "build time",
              "final round", "build / final round", "tails / tolerance", "error / tolerance"]
    with tempfile.TemporaryDirectory() as tmp, published(__file__, "The automatic resolution's rounds", options.variant):
        builds = [("this tree", ROOT)]
        if options.baseline:
            builds.append((options.baseline, baseline_tree(options.baseline, Path(tmp))))
        print("| " + " | ".join(header) + " |")
        print("|" + " --- |" * len(header))
        for name in options.problems:
            runs = {label: [build(source, name)] for label, source in builds}
            if max(seconds(r[0]) for r in runs.values()) < QUICK:  # a second or two: the median of several
                for _ in range(REPEATS - 1):
                    for label, source in builds:
                        runs[label].append(build(source, name))
            times = {}
            for label, _ in builds:
                run = sorted(runs[label], key=seconds)[len(runs[label]) // 2]
                times[label] = seconds(run)
                print("| " + " | ".join([Path(name).stem, label] + summary(run, len(runs[label]))) + " |", flush=True)
            if options.baseline:
                ratio = times[options.baseline] / times["this tree"]
                print(f"| {Path(name).stem} | {options.baseline} / this tree | | | | {ratio:.2f} | | | | |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
