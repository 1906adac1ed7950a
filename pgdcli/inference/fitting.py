"""Parameter identification from data with a codebook as the model (``pgd fit``).

The free coordinates (parameters, initial conditions) are estimated by
nonlinear least squares, ``scipy.optimize.least_squares`` (trust-region
reflective, bounds = the coordinates' domains), with the residual

    r = (codebook(data coordinates, free, fixed)[u] - data[u]) / sigma[u]

over the observed unknowns ``u`` and the data rows, and its Jacobian from
:meth:`Codebook.gradient` (exact derivatives of the interpolants). Several
starts (the box centre, then scrambled Sobol points) guard against local
minima; the best is kept. Standard errors are ``sqrt(diag(s^2 (J^T J)^-1))``,
``s^2 = sum r^2 / (m - n)``. The estimate is then checked: the problem is
re-solved at it by the independent reference (:mod:`pgdcli.checks.reference`) and
the codebook-vs-reference misfit at the data points is reported.

Data columns: one per known coordinate (the time coordinate is required when
the problem has one), one per observed unknown (a subset is fine), and
optional ``sigma_<unknown>`` columns (per-row standard deviations).
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from ..checks.reference import solve_reference
from ..codebook.codebook import Codebook
from ..codebook.phases import refuse_phases
from ..codebook.gradient import TrajectoryModel
from ..errors import PgdError
from .data import FitError, check_finite, fixed_values, read_data, split_columns

__all__ = ["FitError", "FitResult", "fit", "read_data", "sobol_starts"]


@dataclass
class FitResult:
    """Outcome of :func:`fit`.

    Attributes
    ----------
    estimate, stderr : dict of str to float
        Free coordinate -> estimate and its standard error (inf when not identifiable).
    fixed : dict of str to float
        Coordinates held by ``fix``.
    cost : float
        ``0.5 * sum r^2`` at the estimate; ``rms`` = ``sqrt(sum r^2 / m)``.
    residuals : ndarray, shape (m,)
        Weighted residuals, observed unknown by unknown (rows inner).
    jacobian : ndarray, shape (m, n)
        Their Jacobian with respect to the free coordinates at the estimate.
    fitted : dict of str to ndarray, shape (rows,)
        The data's coordinate columns (names in ``coordinates``) and every unknown of the
        codebook at the estimate; ``data`` holds the observed columns.
    reference_error : float or None
        Max abs difference codebook - reference at the data points (all unknowns), at the estimate.
    reference_rms : float or None
        ``rms`` with the reference solution in place of the codebook.
    success : bool
        The least-squares solve converged and no estimate lies on a bound of its domain.
    message : str
        One line: ``least_squares``' termination reason, and the coordinates on a bound.
    at_bound : list of str
        Free coordinates whose estimate lies on a bound of their domain (within 1e-9 of its
        width): the best fit may lie outside the codebook, and ``success`` is False.
    bounds : dict of str to tuple of float
        Free coordinate -> ``(low, high)``, the domain searched.
    nfev, starts : int
        Residual evaluations over all starts, and the number of starts.
    elapsed, check_elapsed : float
        Seconds spent fitting (loading the codebook and reading the data excluded) and in the reference check.
    """

    estimate: dict
    stderr: dict
    fixed: dict
    cost: float
    rms: float
    residuals: np.ndarray
    success: bool
    message: str
    nfev: int
    starts: int
    fitted: dict
    observed: list
    reference_error: float | None = None
    reference_rms: float | None = None
    elapsed: float = 0.0
    check_elapsed: float = 0.0
    reference_message: str = ""
    data: dict = field(default_factory=dict, repr=False)
    coordinates: list = field(default_factory=list)
    jacobian: np.ndarray | None = field(default=None, repr=False)
    at_bound: list = field(default_factory=list)
    bounds: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Plain Python data (what ``pgd fit --format json`` prints)."""
        def num(v):
            return None if v is None or not math.isfinite(v) else float(v)

        return {"estimate": {k: float(v) for k, v in self.estimate.items()},
                "stderr": {k: num(v) for k, v in self.stderr.items()},
                "fixed": dict(self.fixed), "cost": float(self.cost), "rms": float(self.rms),
                "residuals": int(self.residuals.size), "success": bool(self.success), "message": self.message,
                "at_bound": list(self.at_bound),
                "evaluations": int(self.nfev), "starts": int(self.starts), "observed": list(self.observed),
                "reference_error": num(self.reference_error), "reference_rms": num(self.reference_rms),
                "reference_message": self.reference_message, "elapsed": float(self.elapsed),
                "check_elapsed": float(self.check_elapsed),
                "fitted": {k: [float(x) for x in v] for k, v in self.fitted.items()}}


# ----------------------------------------------------------------------------------------------
# the model: values and Jacobian of the weighted residual
# ----------------------------------------------------------------------------------------------
class _Model:
    """Weighted residuals and their Jacobian in the free coordinates, for one data set.

    When at most one data coordinate varies (a trajectory), a :class:`~pgdcli.codebook.gradient.TrajectoryModel`
    along it gives values and Jacobian in one sweep per call (cached for the Jacobian call at the same
    point); otherwise :meth:`Codebook.evaluate` and :meth:`Codebook.gradient` at every row.
    """

    def __init__(self, cb, coords, observed, sigma, fixed, free):
        self.cb, self.observed, self.free = cb, observed, free
        rows = len(next(iter(coords.values()))) if coords else 1
        self.rows = rows
        self.weight = np.concatenate([1.0 / np.broadcast_to(sigma.get(u, 1.0), (rows,)) for u in observed])
        varying = [n for n, v in coords.items() if np.ptp(v) > 0]
        self.grid = len(varying) <= 1
        self.base = {n: (v if n in varying else v[:1]) for n, v in coords.items()}
        self.base.update({n: np.array([v]) for n, v in fixed.items()})
        self.trajectory = None
        if self.grid and coords:
            axis = varying[0] if varying else next(iter(coords))
            self.trajectory = TrajectoryModel(cb, axis, coords[axis], observed)
            self.axis_values = coords[axis]
            names = cb.coordinate_names
            self.point = np.array([float(self.base[n][0]) if n in self.base else np.nan for n in names])
            self.slots = [names.index(n) for n in free]
        self._cache = (None, None)

    def _coords(self, x: np.ndarray) -> dict:
        out = dict(self.base)
        out.update({n: np.array([v]) for n, v in zip(self.free, x)})
        return out

    def values(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """Every unknown at the data rows for the free coordinates ``x``: shape (rows,) each."""
        if self.trajectory is not None:
            names = self.cb.unknown_names
            axis = self.cb.coordinate_names[self.trajectory.axis]
            point = self.point.copy()
            point[self.slots] = x
            every = TrajectoryModel(self.cb, axis, self.axis_values, names).evaluate(point)
            return dict(zip(names, every[:, :, 0]))
        coords = self._coords(x)
        if self.grid:
            return {u: np.broadcast_to(v.reshape(-1), (self.rows,)).copy()
                    for u, v in self.cb.evaluate_grid(coords).items()}
        return {u: np.broadcast_to(v, (self.rows,)).copy() for u, v in self.cb.evaluate(coords).items()}

    def _sweep(self, x: np.ndarray) -> np.ndarray:
        """(observed, rows, 1 + free): values and derivatives along the trajectory, cached for the last x."""
        key, out = self._cache
        if key is None or not np.array_equal(key, x):
            point = self.point.copy()
            point[self.slots] = x
            out = self.trajectory.evaluate(point, self.slots)
            self._cache = (np.array(x, copy=True), out)
        return out

    def residual(self, x: np.ndarray, data: Mapping[str, np.ndarray]) -> np.ndarray:
        if self.trajectory is not None:
            vals = dict(zip(self.observed, self._sweep(x)[:, :, 0]))
        else:
            vals = self.values(x)
        return np.concatenate([vals[u] - data[u] for u in self.observed]) * self.weight

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        if self.trajectory is not None:
            sweep = self._sweep(x)[:, :, 1:]  # (observed, rows, free)
            return sweep.reshape(-1, len(self.free)) * self.weight[:, None]
        g = self.cb.gradient(self._coords(x), wrt=self.free, fields=self.observed)
        cols = [np.concatenate([np.broadcast_to(g[u][c].reshape(-1), (self.rows,)) for u in self.observed])
                for c in self.free]
        return np.stack(cols, axis=1) * self.weight[:, None]


def sobol_starts(bounds, count: int, seed: int) -> np.ndarray:
    """The starts :func:`fit` uses: the box centre, then scrambled Sobol points in the box.

    Parameters
    ----------
    bounds : array_like, shape (2, n)
        Lower and upper bounds.
    count : int
    seed : int

    Returns
    -------
    ndarray, shape (count, n)
    """
    bounds = np.asarray(bounds, dtype=float)
    lo, hi = bounds
    points = [0.5 * (lo + hi)]
    if count > 1:
        from scipy.stats import qmc  # ~0.2 s to import: only when asked for

        m = max(0, math.ceil(math.log2(count - 1)))
        unit = qmc.Sobol(lo.size, scramble=True, seed=seed).random_base2(m)[: count - 1]
        points.extend(lo + unit * (hi - lo))
    return np.array(points)


def _stderr(jac: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """``sqrt(diag(s^2 (J^T J)^-1))``; inf for a coordinate the data cannot determine (it has a component
    in the null space of ``J``)."""
    m, n = jac.shape
    s2 = float(residuals @ residuals) / (m - n)
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    keep = sv > sv[0] * max(m, n) * np.finfo(float).eps if sv[0] > 0 else np.zeros(n, dtype=bool)
    cov = (vt[keep].T / sv[keep] ** 2) @ vt[keep] * s2
    out = np.sqrt(np.diag(cov))
    out[np.any(np.abs(vt[~keep]) > 1e-8, axis=0)] = np.inf
    return out


# ----------------------------------------------------------------------------------------------
# the fit
# ----------------------------------------------------------------------------------------------
def fit(codebook, data, *, fix: Mapping[str, float] | None = None, sigma: Mapping[str, float] | None = None,
        starts: int = 8, seed: int = 0, tolerance: float = 1e-12, check: bool = True,
        label: str | None = None) -> FitResult:
    """Estimate the free coordinates that best explain observed data.

    Parameters
    ----------
    codebook : Codebook or path
    data : mapping of str to array_like (rows,), or a CSV path / file-like (see :func:`read_data`)
        Known coordinates (the time coordinate at least), observed unknowns, optional
        ``sigma_<unknown>`` columns.
    fix : mapping, optional
        Coordinates held at given values (not estimated).
    sigma : mapping, optional
        Unknown -> standard deviation of its data (a constant; a ``sigma_<unknown>`` column
        gives one per row). Default 1.
    starts : int
        Local solves: the box centre, then ``starts - 1`` scrambled Sobol points.
    seed : int
        Seed of the Sobol scrambling.
    tolerance : float
        ``ftol``, ``xtol`` and ``gtol`` of ``least_squares``.
    check : bool
        Re-solve at the estimate with the independent reference and report the misfit.

    Returns
    -------
    FitResult

    Raises
    ------
    FitError
        Unreadable or invalid data, unknown or out-of-domain fixed coordinates, nothing free,
        fewer residuals than free coordinates.
    """
    from scipy.optimize import least_squares  # noqa: F401 -- imported before `began`, as qmc below


    cb = codebook if isinstance(codebook, Codebook) else Codebook.load(codebook)
    refuse_phases(cb, "fit")
    if not isinstance(data, Mapping):
        data = read_data(data, label)
    if int(starts) > 1:
        from scipy.stats import qmc  # noqa: F401 -- imported here (~0.2 s) so that `elapsed` is the fit's
    began = _time.perf_counter()
    label = label or "DATA"
    data = {k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in data.items()}
    check_finite(data, label)
    coords, observed, sig = split_columns(cb, data, label)
    _add_sigma(sig, sigma, observed, data)
    fixed = fixed_values(cb, fix, coords)
    free = [n for n in cb.coordinate_names if n not in coords and n not in fixed]
    if not free:
        raise FitError("nothing to fit: every coordinate is a data column or fixed")
    model = _Model(cb, coords, observed, sig, fixed, free)
    m = model.rows * len(observed)
    if m <= len(free):
        raise FitError(f"{label}: {m} data values for {len(free)} free coordinates; need more values than unknowns")
    if int(starts) < 1:
        raise FitError(f"starts must be at least 1, got {starts}")
    bounds = np.array([[cb.coordinate(n).domain[0] for n in free], [cb.coordinate(n).domain[1] for n in free]])
    best, nfev = _best_of_starts(model, data, bounds, int(starts), seed, tolerance)
    jac = model.jacobian(best.x)
    errors = _stderr(jac, best.fun)
    fitted = {n: v.copy() for n, v in coords.items()}
    fitted.update(model.values(best.x))
    at_bound = _at_bound(best.x, free, bounds)
    result = FitResult(
        estimate=dict(zip(free, map(float, best.x))), stderr=dict(zip(free, map(float, errors))), fixed=fixed,
        cost=float(best.cost), rms=float(np.sqrt(2 * best.cost / m)), residuals=best.fun,
        success=bool(best.success) and not at_bound, message=_message(best, at_bound), nfev=nfev,
        starts=int(starts), fitted=fitted, observed=observed, data={u: data[u] for u in observed},
        coordinates=list(coords), jacobian=jac, at_bound=at_bound,
        bounds={n: (float(lo), float(hi)) for n, lo, hi in zip(free, *bounds)})
    result.elapsed = _time.perf_counter() - began
    if check:
        began = _time.perf_counter()
        _reference_check(cb, result, coords, model, label)
        result.check_elapsed = _time.perf_counter() - began
    return result


def _add_sigma(sig: dict, sigma: Mapping[str, float] | None, observed, data) -> None:
    """``--sigma`` constants into ``sig`` (unknown -> per-row sigma) where no column gave one."""
    for u, s in (sigma or {}).items():
        if u not in observed:
            raise FitError(f"--sigma {u}: not an observed unknown (observed: {', '.join(observed)})")
        if not float(s) > 0:
            raise FitError(f"--sigma {u}={s}: must be positive")
        sig.setdefault(u, np.full(len(data[u]), float(s)))


def _best_of_starts(model, data, bounds: np.ndarray, starts: int, seed: int, tolerance: float) -> tuple:
    """The least-squares solve of lowest cost over the Sobol starts, and the evaluations of all of them."""
    from scipy.optimize import least_squares

    best, nfev = None, 0
    for x0 in sobol_starts(bounds, starts, seed):
        res = least_squares(model.residual, x0, jac=lambda x, *_: model.jacobian(x), bounds=bounds, method="trf",
                            x_scale="jac", ftol=tolerance, xtol=tolerance, gtol=tolerance, args=(data,))
        nfev += res.nfev
        if best is None or res.cost < best.cost:
            best = res
    return best, nfev


def _at_bound(x: np.ndarray, free: Sequence[str], bounds: np.ndarray) -> list[str]:
    """The free coordinates whose estimate is on a bound of the domain (within 1e-9 of its width)."""
    span = bounds[1] - bounds[0]
    return [n for n, v, lo, hi, s in zip(free, x, *bounds, span) if min(v - lo, hi - v) <= 1e-9 * s]


def _message(res, at_bound: Sequence[str]) -> str:
    text = " ".join(str(res.message).split()).rstrip(".")
    if at_bound:
        text += f"; at the domain bound: {', '.join(at_bound)} (the best fit may lie outside the codebook)"
    return text


def _reference_check(cb, result: FitResult, coords: Mapping, model: _Model, label: str) -> None:
    """Re-solve at the estimate with the independent reference; store the misfits."""
    from ..problem.spec import parse_spec

    try:
        problem = parse_spec(cb.spec_text, source=f"{cb.name} (embedded spec)", allow_nonlinear=True)
    except PgdError as exc:
        result.reference_message = f"not checked: {exc}"
        return
    time = problem.time
    values = {**coords, **{n: np.array([v]) for n, v in result.fixed.items()},
              **{n: np.array([v]) for n, v in result.estimate.items()}}
    rows = model.rows
    # one reference sample per distinct point of the other coordinates, one time column per distinct time
    others = [c.name for c in cb.coordinates if c.name != time]
    inverse, params = np.zeros(rows, dtype=int), {}
    if others:
        table = np.column_stack([np.broadcast_to(values[n], (rows,)) for n in others])
        unique, inverse = np.unique(table, axis=0, return_inverse=True)
        params = {n: unique[:, j] for j, n in enumerate(others)}
    times, columns = None, None
    if time is not None:
        times, columns = np.unique(np.broadcast_to(values[time], (rows,)), return_inverse=True)
    ref = solve_reference(problem, params, times)
    if not ref.success.all():
        result.reference_message = f"reference failed: {next(m for m in ref.messages if m)}"
        return
    inverse = np.asarray(inverse).reshape(-1)
    refvals = {u: (np.asarray(v)[inverse] if time is None else np.asarray(v)[inverse, np.asarray(columns).reshape(-1)])
               for u, v in ref.values.items()}
    result.reference_error = float(max(np.max(np.abs(result.fitted[u] - refvals[u])) for u in refvals))
    r = np.concatenate([refvals[u] - result.data[u] for u in result.observed]) * model.weight
    result.reference_rms = float(np.sqrt(np.mean(r * r)))
    result.reference_message = f"reference: solve_ivp {ref.method} rtol {ref.rtol:g} atol {ref.atol:g}"
