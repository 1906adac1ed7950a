"""Parameter identification with a codebook (``pgdcli.fit``) beside least_squares over solve_ivp; C export speed.

Part 1, fit speed. For each problem the codebook is solved once (the offline cost, reported
apart), synthetic data are made by the independent reference (solve_ivp DOP853, 1e-12) at known
coordinates plus Gaussian noise, and the same ``scipy.optimize.least_squares`` (trust-region
reflective, bounds = the codebook's domains, ``x_scale='jac'``, ftol = xtol = gtol = 1e-12), from
the same starts (the box centre then scrambled Sobol points: ``pgdcli.inference.fitting.sobol_starts``),
fits the same data with two models:

- pgdcli: the codebook, Jacobian from ``Codebook.gradient`` (``pgdcli.fit(..., check=False)``);
- scipy: one ``solve_ivp`` call per evaluation (DOP853, rtol = atol = 1e-10, ``t_eval`` = the
  data times, a hand-written numpy right-hand side), Jacobian by least_squares' finite
  differences (n extra solves per Jacobian).

Both keep the best of their starts. A third column times least_squares alone, same starts and
settings, on a model that costs nothing (the residual linearized at pgd's estimate): no model can
make a fit faster than that, so scipy's time over it bounds the ratio any codebook could reach. Reported: medians of the wall times (the two fits interleaved,
so that both see the same load of the shared machine), ratio, both estimates,
their largest difference in units of pgdcli's standard errors, and the truth.

Part 2, C export. The codebook is exported (``pgd export --to c``), compiled with the system cc
(-O2 and -O3 -march=native) into a shared library whose loop evaluates 20,000 random points
(ctypes calls the loop once); per point beside ``Codebook`` (one point given as Python floats,
and a batch of 1e5 points).

    python benchmarks/fit_speed.py [--quick]   # --quick: coupled and relaxation, fewer repeats

The tables are printed and written to benchmarks/results/fit_speed.md.
"""

from __future__ import annotations

import argparse
import ctypes
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


# ----------------------------------------------------------------------------------------------
# the problems: truth, data, and the right-hand side the scipy model integrates
# ----------------------------------------------------------------------------------------------
def _coupled(t, y):
    u1, u2, u3 = y
    return [1 - u2 * u3, 2 - u1 * u3, 3 - u1 * u2]


_RB = dict(m=1.0, M=(0.2, 0.5, 0.8), I=(1.0, 1.5, 2.0), J=(0.1, 0.2, 0.3), fg3=-0.5)


def _rigid_body(t, y):
    u1, u2, u3, w1, w2, w3 = y
    m, (M1, M2, M3), (I1, I2, I3), (J1, J2, J3), fg3 = _RB["m"], _RB["M"], _RB["I"], _RB["J"], _RB["fg3"]
    return [((m + M2) * u2 * w3 - (m + M3) * u3 * w2) / (m + M1),
            ((m + M3) * u3 * w1 - (m + M1) * u1 * w3) / (m + M2),
            ((m + M1) * u1 * w2 - (m + M2) * u2 * w1 + fg3) / (m + M3),
            (((J2 + I2) - (J3 + I3)) * w2 * w3 + (M2 - M3) * u2 * u3) / (J1 + I1),
            (((J3 + I3) - (J1 + I1)) * w3 * w1 + (M3 - M1) * u3 * u1) / (J2 + I2),
            (((J1 + I1) - (J2 + I2)) * w1 * w2 + (M1 - M2) * u1 * u2) / (J3 + I3)]


def _relaxation(params):
    k, a = params["k"], params["a"]
    return lambda t, y: [-k * y[0] + a * np.sin(2 * t)]


# name: (truth, times, observed, noise, rhs(params) -> f(t, y), y0(params))
CASES = {
    "coupled": ({"a": 0.3, "b": 0.7, "c": 0.45}, np.linspace(0, 0.5, 41), ["u1", "u2"], 1e-3,
                lambda p: _coupled, lambda p: [p["a"], p["b"], p["c"]]),
    "rigid_body": ({"u10": 0.8, "u20": 1.3, "u30": 0.6, "w10": 1.1, "w20": 0.7, "w30": 1.4}, np.linspace(0, 1, 31),
                   ["u1", "u2", "u3", "w1", "w2", "w3"], 2e-3, lambda p: _rigid_body,
                   lambda p: [p["u10"], p["u20"], p["u30"], p["w10"], p["w20"], p["w30"]]),
    "relaxation": ({"k": 1.7, "a": 0.4, "u0": 0.65}, np.linspace(0, 3, 60), ["u"], 1e-3, _relaxation,
                   lambda p: [p["u0"]]),
}


def _data(name, problem):
    from pgdcli.checks.reference import solve_reference

    truth, times, observed, noise, _, _ = CASES[name]
    ref = solve_reference(problem, {k: np.array([v]) for k, v in truth.items()}, times)
    rng = np.random.default_rng(0)
    return {"t": times, **{u: ref.values[u][0] + rng.normal(0, noise, times.size) for u in observed}}


def _scipy_fit(name, cb, data, starts, free):
    from scipy.integrate import solve_ivp
    from scipy.optimize import least_squares

    from pgdcli.inference.fitting import sobol_starts

    _, times, observed, _, rhs, y0 = CASES[name]
    index = [cb.unknown_names.index(u) for u in observed]
    target = np.concatenate([data[u] for u in observed])

    def residual(x):
        p = dict(zip(free, x))
        sol = solve_ivp(rhs(p), (0.0, times[-1]), y0(p), method="DOP853", t_eval=times, rtol=1e-10, atol=1e-10)
        return np.concatenate([sol.y[i] for i in index]) - target

    bounds = np.array([[cb.coordinate(n).domain[0] for n in free], [cb.coordinate(n).domain[1] for n in free]])
    best, nfev = None, 0
    for x0 in sobol_starts(bounds, starts, 0):
        res = least_squares(residual, x0, bounds=bounds, method="trf", x_scale="jac", ftol=1e-12, xtol=1e-12,
                            gtol=1e-12)
        nfev += res.nfev + res.njev * len(free)
        best = res if best is None or res.cost < best.cost else best
    return best, nfev


def _floor_fit(cb, res, starts):
    """least_squares alone: the same starts and settings on a model that costs nothing (the pgd fit's
    residual linearized at its estimate, a precomputed matrix), i.e. what no model can undercut."""
    from scipy.optimize import least_squares

    from pgdcli.inference.fitting import sobol_starts

    free = list(res.estimate)
    x_star = np.array([res.estimate[n] for n in free])
    jac = np.asarray(res.jacobian)
    r_star = res.residuals
    bounds = np.array([[cb.coordinate(n).domain[0] for n in free], [cb.coordinate(n).domain[1] for n in free]])
    t0 = time.perf_counter()
    for x0 in sobol_starts(bounds, starts, 0):
        least_squares(lambda x: r_star + jac @ (x - x_star), x0, jac=lambda x: jac, bounds=bounds, method="trf",
                      x_scale="jac", ftol=1e-12, xtol=1e-12, gtol=1e-12)
    return time.perf_counter() - t0


def _median_time(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def fit_rows(names, repeats, starts):
    import pgdcli
    from pgdcli.problem.spec import load_spec

    rows, books = [], {}
    for name in names:
        problem = load_spec(ROOT / "problems" / f"{name}.yaml")
        t0 = time.perf_counter()
        cb = pgdcli.solve(problem).codebook
        build = time.perf_counter() - t0
        books[name] = cb
        data = _data(name, problem)
        pgdcli.fit(cb, data, starts=starts, check=False)  # warm-up: imports
        checked = pgdcli.fit(cb, data, starts=starts)
        free = list(checked.estimate)
        # interleaved: pgd, scipy, pgd, scipy, ... (scipy fewer times), so that both see the same load
        pgd_times, sci_times = [], []
        for r in range(repeats):
            t, res = _median_time(lambda: pgdcli.fit(cb, data, starts=starts, check=False), 1)
            pgd_times.append(t)
            if r < max(1, repeats // 2):
                t, (sci, sci_nfev) = _median_time(lambda: _scipy_fit(name, cb, data, starts, free), 1)
                sci_times.append(t)
        t_pgd, t_sci = statistics.median(pgd_times), statistics.median(sci_times)
        floor = statistics.median(_floor_fit(cb, res, starts) for _ in range(repeats))
        diff = max(abs(res.estimate[n] - s) / res.stderr[n] for n, s in zip(free, sci.x))
        truth = CASES[name][0]
        rows.append({"problem": name, "build": build, "pgd": t_pgd, "pgd_nfev": res.nfev, "scipy": t_sci,
                     "scipy_nfev": sci_nfev, "ratio": t_sci / t_pgd, "diff": diff,
                     "pgd_est": [res.estimate[n] for n in free], "scipy_est": list(sci.x),
                     "stderr": [res.stderr[n] for n in free], "truth": [truth[n] for n in free],
                     "check": checked.reference_error, "check_time": checked.check_elapsed, "floor": floor})
    return rows, books


# ----------------------------------------------------------------------------------------------
# part 2: the C export beside Codebook
# ----------------------------------------------------------------------------------------------
_DRIVER = """#include "{header}"
void loop(int n, const double *x, double *out) {{
    int i;
    for (i = 0; i < n; ++i) {prefix}_eval(x + i * {upper}_NCOORDS, out + i * {upper}_NOUT);
}}
void loop_f(int n, const float *x, float *out) {{
    int i;
    for (i = 0; i < n; ++i) {prefix}_eval_f(x + i * {upper}_NCOORDS, out + i * {upper}_NOUT);
}}
"""


def _compile(cb, directory: Path, flags: list[str]):
    from pgdcli.codebook.export import export

    files, _ = export(cb, "c", force=True)
    ((header, text),) = files.items()
    (directory / header).write_text(text)
    prefix = header[:-2]
    (directory / "loop.c").write_text(_DRIVER.format(header=header, prefix=prefix, upper=prefix.upper()))
    # a path per codebook and flags: dlopen hands back an already loaded library for a path it has seen
    lib = directory / f"loop_{prefix}{'_'.join(flags).replace('=', '')}.so"
    subprocess.run([shutil.which("cc"), *flags, "-std=c99", "-shared", "-fPIC", "-o", str(lib),
                    str(directory / "loop.c")], check=True)
    return ctypes.CDLL(str(lib))


def _c_per_point(lib, points, nout, single, repeats):
    dtype = np.float32 if single else np.float64
    x = np.ascontiguousarray(points, dtype=dtype)
    out = np.empty((len(points), nout), dtype=dtype)
    fn = lib.loop_f if single else lib.loop
    args = (ctypes.c_int(len(points)), x.ctypes.data_as(ctypes.c_void_p), out.ctypes.data_as(ctypes.c_void_p))
    t, _ = _median_time(lambda: fn(*args), repeats)
    return t / len(points), out


def c_rows(books, repeats):
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, cb in books.items():
            rng = np.random.default_rng(1)
            points = np.column_stack([rng.uniform(*c.domain, 20000) for c in cb.coordinates])
            row = {"problem": name}
            for label, flags in (("O2", ["-O2"]), ("O3", ["-O3", "-march=native"])):
                lib = _compile(cb, Path(tmp), flags)
                row[label], out = _c_per_point(lib, points, len(cb.unknown_names), False, repeats)
                row[label + "_f"], _ = _c_per_point(lib, points, len(cb.unknown_names), True, repeats)
            ref = cb.evaluate(dict(zip(cb.coordinate_names, points.T)))
            row["max_diff"] = float(np.max(np.abs(out - np.column_stack([ref[u] for u in cb.unknown_names]))))
            one = {c.name: float(v) for c, v in zip(cb.coordinates, points[0])}
            cb(**one)
            per_call = []
            for _ in range(repeats * 3):
                t0 = time.perf_counter()
                for _ in range(200):
                    cb(**one)
                per_call.append((time.perf_counter() - t0) / 200)
            row["single"] = statistics.median(per_call)
            batch = {c.name: np.repeat(points[:, j], 5) for j, c in enumerate(cb.coordinates)}
            t, _ = _median_time(lambda: cb.evaluate(batch), max(1, repeats // 2))
            row["batch"] = t / 1e5
            rows.append(row)
    return rows


def _us(seconds: float) -> str:
    return f"{seconds * 1e6:.2f} us" if seconds < 1e-3 else f"{seconds * 1e3:.1f} ms"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coupled and relaxation only, fewer repeats")
    parser.add_argument("--starts", type=int, default=8, help="starts for both fits [8]")
    args = parser.parse_args()
    names = ["coupled", "relaxation"] if args.quick else ["coupled", "relaxation", "rigid_body"]
    repeats = 3 if args.quick else 7
    rows, books = fit_rows(names, repeats, args.starts)
    print(f"Fit ({args.starts} starts, same data, same least_squares; scipy model: solve_ivp DOP853 1e-10 per "
          "evaluation, finite-difference Jacobian)\n")
    print("| problem | codebook build (once) | pgd fit | evaluations | least_squares + solve_ivp | evaluations (solves) "
          "| ratio | max estimate difference / stderr | reference check of the fit | least_squares alone (free model) "
          "| scipy / that floor |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['problem']} | {r['build']:.2f} s | {_us(r['pgd'])} | {r['pgd_nfev']} | {_us(r['scipy'])} | "
              f"{r['scipy_nfev']} | {r['ratio']:.0f}x | {r['diff']:.1e} | {r['check']:.1e} in {_us(r['check_time'])} | "
              f"{_us(r['floor'])} | {r['scipy'] / r['floor']:.0f}x |")
    print()
    for r in rows:
        est = ", ".join(f"{p:.5f} / {s:.5f} +/- {e:.1e} (true {t})" for p, s, e, t in
                        zip(r["pgd_est"], r["scipy_est"], r["stderr"], r["truth"]))
        print(f"- {r['problem']}: pgd / scipy +/- stderr: {est}")
    crow = c_rows(books, repeats)
    print("\nC export per point (loop of 20,000 random points inside C) beside Codebook\n")
    print("| codebook | C -O2 double | C -O2 float | C -O3 -march=native double | C -O3 -march=native float "
          "| Codebook one point (Python floats) | Codebook batch of 1e5, per point | C vs Codebook max diff |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in crow:
        print(f"| {r['problem']} | {_us(r['O2'])} | {_us(r['O2_f'])} | {_us(r['O3'])} | {_us(r['O3_f'])} | "
              f"{_us(r['single'])} | {_us(r['batch'])} | {r['max_diff']:.1e} |")
    return 0


if __name__ == "__main__":
    from _machine import published

    with published(__file__, "Fit speed and the exported C beside scipy"):
        main()
