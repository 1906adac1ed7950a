"""Print a noisy progress curve of the enzyme example as CSV: the fitting tutorial's "measurements".

The substrate concentration s(t) is integrated with scipy alone (solve_ivp, DOP853 at 1e-12;
no pgdcli code), sampled every half minute, and Gaussian noise is added:

    python docs/examples/enzyme_data.py > progress.csv
    python docs/examples/enzyme_data.py --vmax 2.6 > fast.csv     # an enzyme faster than the codebook's domain
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy.integrate import solve_ivp


def progress_curve(vmax: float, km: float, s0: float, times: np.ndarray) -> np.ndarray:
    """s(t) of ds/dt = -vmax s / (km + s), s(0) = s0, at ``times``."""
    sol = solve_ivp(lambda t, s: -vmax * s / (km + s), (0.0, float(times[-1])), [s0], method="DOP853",
                    t_eval=times, rtol=1e-12, atol=1e-12)
    return sol.y[0]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vmax", type=float, default=1.2, help="maximal rate, mM/min [1.2]")
    parser.add_argument("--km", type=float, default=2.0, help="Michaelis constant, mM [2.0]")
    parser.add_argument("--s0", type=float, default=8.0, help="initial substrate, mM [8.0]")
    parser.add_argument("--noise", type=float, default=0.05, help="standard deviation of the noise, mM [0.05]")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    times = np.linspace(0.0, 10.0, 21)
    s = progress_curve(args.vmax, args.km, args.s0, times)
    s += np.random.default_rng(args.seed).normal(0.0, args.noise, times.size)
    print("t,s")
    for t, value in zip(times, s):
        print(f"{float(t)!r},{float(value)!r}")
    print(f"true values: vmax {args.vmax}, km {args.km}, s0 {args.s0}; noise {args.noise}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
