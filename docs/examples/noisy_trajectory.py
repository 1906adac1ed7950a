"""Print a noisy rigid-body trajectory as CSV: the "measurements" of the rigid-body fit in the docs.

The trajectory is integrated by pgdcli's independent reference (scipy solve_ivp, DOP853,
rtol = atol = 1e-12) from known initial velocities, sampled at equally spaced times, and
Gaussian noise is added to the observed columns:

    python docs/examples/noisy_trajectory.py > trajectory.csv
    python docs/examples/noisy_trajectory.py --observe u1,u2,u3 --noise 0.005 --seed 3 > trajectory.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from pgdcli.checks.reference import solve_reference
from pgdcli.problem.spec import load_spec

ROOT = Path(__file__).resolve().parents[2]
TRUTH = {"u10": 0.8, "u20": 1.3, "u30": 0.6, "w10": 1.1, "w20": 0.7, "w30": 1.4}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--observe", default="u1,u2,u3,w1,w2,w3", help="unknowns to print [all six]")
    parser.add_argument("--times", type=int, default=41, help="samples on t in [0, 1] [41]")
    parser.add_argument("--noise", type=float, default=0.01, help="standard deviation of the noise [0.01]")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    problem = load_spec(ROOT / "problems" / "rigid_body.yaml")
    times = np.linspace(0.0, 1.0, args.times)
    ref = solve_reference(problem, {k: np.array([v]) for k, v in TRUTH.items()}, times)
    rng = np.random.default_rng(args.seed)
    observed = args.observe.split(",")
    columns = [times] + [ref.values[u][0] + rng.normal(0.0, args.noise, times.size) for u in observed]
    print(",".join(["t"] + observed))
    for row in zip(*columns):
        print(",".join(repr(float(v)) for v in row))
    print(f"true initial velocities: {TRUTH}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
