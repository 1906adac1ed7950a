"""Variance-based sensitivity of a codebook: means, variances and Sobol indices, exactly.

The coordinates that are neither time nor held fixed are independent random inputs (uniform over
their domains unless a density is given). For each unknown, at given times, :func:`sensitivity`
returns its mean and variance over the inputs and the Sobol indices of every input: first order
``S_i = Var(E[u | x_i]) / Var(u)``, total ``ST_i = E[Var(u | x_~i)] / Var(u)`` and, on request,
second order ``S_ij`` (the pair's interaction alone). They are computed from the separated form
by one-dimensional quadratures (:mod:`pgdcli.codebook.densities`) contracted through the modes or
cores (:mod:`pgdcli.codebook.sobol`): no sampling, and exact for the codebook's own function
under uniform densities (to rounding).

numpy only; :meth:`pgdcli.codebook.codebook.Codebook.sensitivity` and ``pgd sensitivity`` call
:func:`sensitivity`.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from ..blas import one_blas_thread
from ..errors import QueryError
from .densities import Density, parse_density, quadrature
from .evaluate import shared_basis
from .fields import TT
from .sobol import Patterns, cp_patterns, cp_terms, tt_patterns, tt_terms

__all__ = ["SensitivityResult", "sensitivity", "DEFAULT_TIMES", "ROUNDING_STD"]

DEFAULT_TIMES = 11  # times over the time domain when none are given
# below this standard deviation relative to the unknown's RMS over time and inputs, the variance is
# rounding (an initial value that no input changes) and the indices are NaN
ROUNDING_STD = 1e-12


@dataclass
class SensitivityResult:
    """Means, variances and Sobol indices of the unknowns of a codebook.

    Attributes
    ----------
    inputs : list of str
        The random coordinates, in codebook order (the last axis of ``first``, ``total``).
    time : str or None
        The time coordinate (None for a steady codebook).
    times : ndarray, shape (T,)
        The times (a steady codebook: one entry, NaN).
    at : dict
        Coordinates held fixed -> value.
    densities : dict
        Input -> description of its density (``uniform`` ...).
    mean, variance : dict of str to ndarray, shape (T,)
    first, total : dict of str to ndarray, shape (T, d)
        NaN where the variance is zero (to rounding).
    second : dict of str to ndarray, shape (T, d, d), or None
        Symmetric, zero diagonal; None unless asked.
    seconds : float
        Wall time of the computation.
    """

    inputs: list
    time: str | None
    times: np.ndarray
    at: dict
    densities: dict
    mean: dict
    variance: dict
    first: dict
    total: dict
    second: dict | None = None
    seconds: float = 0.0
    unknowns: list = field(default_factory=list)

    def rows(self) -> list[dict]:
        """One flat row per (unknown, time): ``unknown, <time>, mean, variance, first_<i>..., total_<i>...,
        second_<i>_<j>...`` (the CSV layout of ``pgd sensitivity``)."""
        out = []
        for u in self.unknowns:
            for k, t in enumerate(self.times):
                row = {"unknown": u}
                if self.time is not None:
                    row[self.time] = float(t)
                row["mean"] = float(self.mean[u][k])
                row["variance"] = float(self.variance[u][k])
                row.update({f"first_{c}": float(self.first[u][k, i]) for i, c in enumerate(self.inputs)})
                row.update({f"total_{c}": float(self.total[u][k, i]) for i, c in enumerate(self.inputs)})
                if self.second is not None:
                    for i, a in enumerate(self.inputs):
                        for j in range(i + 1, len(self.inputs)):
                            row[f"second_{a}_{self.inputs[j]}"] = float(self.second[u][k, i, j])
                out.append(row)
        return out

    def to_dict(self) -> dict:
        """Plain Python data (JSON has no NaN: None in its place)."""
        def clean(a):
            return [None if not np.isfinite(v) else float(v) for v in np.asarray(a, dtype=float).reshape(-1)]

        unknowns = {}
        for u in self.unknowns:
            entry = {"mean": clean(self.mean[u]), "variance": clean(self.variance[u]),
                     "first": {c: clean(self.first[u][:, i]) for i, c in enumerate(self.inputs)},
                     "total": {c: clean(self.total[u][:, i]) for i, c in enumerate(self.inputs)}}
            if self.second is not None:
                entry["second"] = {f"{a},{self.inputs[j]}": clean(self.second[u][:, i, j])
                                   for i, a in enumerate(self.inputs) for j in range(i + 1, len(self.inputs))}
            unknowns[u] = entry
        return {"inputs": list(self.inputs), "time": self.time,
                "times": clean(self.times) if self.time is not None else None, "at": dict(self.at),
                "densities": dict(self.densities), "unknowns": unknowns, "seconds": self.seconds}


def _fixed_and_times(cb, at: Mapping[str, float] | None, times) -> tuple[dict, object, np.ndarray]:
    """Checked fixed values, the time coordinate (or None) and the times."""
    fixed = {}
    for name, value in dict(at or {}).items():
        c = cb.coordinate(name)  # QueryError names an unknown coordinate
        if c.role == "time":
            raise QueryError(f"--at {name}: {name!r} is the time coordinate; give its values with --times")
        value = float(value)
        low, high = c.domain
        if not (np.isfinite(value) and low <= value <= high):
            raise QueryError(f"--at {name}={value:g}: outside the domain [{low:g}, {high:g}] of {name!r}")
        fixed[name] = value
    tc = next((c for c in cb.coordinates if c.role == "time"), None)
    if tc is None:
        if times is not None:
            raise QueryError("--times: this codebook has no time coordinate (a steady problem)")
        return fixed, None, np.array([np.nan])
    if times is None:
        values = np.linspace(tc.domain[0], tc.domain[1], DEFAULT_TIMES)
    else:
        values = np.atleast_1d(np.asarray(times, dtype=float))
        if values.ndim != 1 or values.size == 0:
            raise QueryError(f"--times: expected one or more values of {tc.name!r}")
        bad = ~np.isfinite(values) | (values < tc.domain[0]) | (values > tc.domain[1])
        if bad.any():
            raise QueryError(f"--times: {float(values[bad][0])!r} is outside the domain "
                             f"[{tc.domain[0]:g}, {tc.domain[1]:g}] of {tc.name!r}")
    return fixed, tc, values


def _inputs(cb, fixed: dict, tc, densities: Mapping | None) -> list:
    """The random coordinates, after checking that every space coordinate is held fixed."""
    inputs = [c for c in cb.coordinates if c is not tc and c.name not in fixed]
    space = [c.name for c in inputs if c.role == "space"]
    if space:
        raise QueryError(f"--at: give a value for the space coordinate{'s' if len(space) > 1 else ''} "
                         f"{', '.join(space)} (e.g. --at {space[0]}=...); sensitivity is taken at a point in space")
    names = {c.name for c in inputs}
    for name in densities or {}:
        cb.coordinate(name)
        if name not in names:
            raise QueryError(f"--density {name}: {name!r} is not a random input (it is the time coordinate, "
                             f"a space coordinate or held fixed with --at)")
    return inputs


def _rms(fm, random: dict, rows: dict, time_nodes, cache: dict) -> float:
    """The unknown's RMS over the inputs and over time (its nodes, with the basis's quadrature weights):
    the scale at which its variances are rounding."""
    inputs = dict(random)
    if time_nodes is not None:
        inputs[len(inputs)] = time_nodes
    if isinstance(fm, TT):
        value, _ = tt_patterns(fm, inputs, rows, None, cache)
    else:
        value, _ = cp_patterns(fm.weights, fm.factors, inputs, rows, None, cache)
    return float(np.sqrt(max(float(value("P" * len(inputs))[0]), 0.0)))


def _unknown(fm, u: str, random: dict, rows: dict, batch, patterns: Patterns, time_nodes, second_order: bool,
             out: dict) -> None:
    """One unknown's terms, divided by its variance, into ``out``."""
    cache: dict = {}  # the inputs' kernels, shared by the terms and the scale
    if isinstance(fm, TT):
        terms = tt_terms(fm, random, rows, batch, patterns, cache)
    else:
        terms = cp_terms(fm.weights, fm.factors, random, rows, batch, patterns, cache)
    # sums of nonnegative quadratic forms: a negative value is rounding of a zero
    variance = np.maximum(terms["variance"], 0.0)
    rms = _rms(fm, random, rows, time_nodes, cache)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(np.sqrt(variance) > ROUNDING_STD * rms, variance, np.nan)[:, None]
        out["first"][u] = np.maximum(terms["first"], 0.0) / scale
        out["total"][u] = np.maximum(terms["total"], 0.0) / scale
        if second_order:
            out["second"][u] = np.maximum(terms["second"], 0.0) / scale[:, :, None]
    out["mean"][u] = terms["mean"]
    out["variance"][u] = variance


def sensitivity(cb, *, times=None, at: Mapping[str, float] | None = None,
                densities: Mapping[str, Density | str] | None = None, second_order: bool = False,
                fields: Sequence[str] | None = None) -> SensitivityResult:
    """Means, variances and Sobol indices of a codebook's unknowns over its random inputs.

    Parameters
    ----------
    cb : Codebook
    times : array_like, optional
        Times at which to take them (default: 11 over the time domain); none for a steady codebook.
    at : mapping, optional
        Coordinates held fixed (every space coordinate must be); they are not inputs.
    densities : mapping, optional
        Input -> :class:`~pgdcli.codebook.densities.Density` or its text (``uniform:LOW,HIGH``,
        ``normal:MEAN,SD``); default uniform over the domain.
    second_order : bool
        Also the second-order indices of every pair.
    fields : sequence of str, optional
        Unknowns (default all).

    Returns
    -------
    SensitivityResult

    Raises
    ------
    QueryError
        Unknown names, values outside the domains, a space coordinate not held fixed, a bad density.
    """
    start = _time.perf_counter()
    fixed, tc, times_ = _fixed_and_times(cb, at, times)
    inputs = _inputs(cb, fixed, tc, densities)
    selected = cb.unknown_names if fields is None else list(fields)
    for u in selected:
        if u not in cb.fields:
            raise QueryError(f"--field: unknown {u!r}; this codebook has {', '.join(cb.unknown_names)}")
    index = {c.name: j for j, c in enumerate(cb.coordinates)}
    bases = {c.name: shared_basis(c) for c in cb.coordinates}
    described, random = {}, {}
    for i, c in enumerate(inputs):
        given = (densities or {}).get(c.name)
        density = parse_density(given, c.name) if isinstance(given, str) else given
        x, w = quadrature(c.name, bases[c.name], density)
        random[i] = (index[c.name], bases[c.name].interpolation_matrix(x), w)
        described[c.name] = "uniform" if density is None else density.describe()
    rows = {index[n]: bases[n].interpolation_matrix(np.array([v]))[0] for n, v in fixed.items()}
    batch = None if tc is None else (index[tc.name], bases[tc.name].interpolation_matrix(times_))
    patterns = Patterns(len(inputs), second_order)
    # time at its nodes (rows None: the identity), weighted by the basis's quadrature: for the scale only
    time_nodes = None if tc is None else (index[tc.name], None, bases[tc.name].weights / bases[tc.name].weights.sum())
    out = {"mean": {}, "variance": {}, "first": {}, "total": {}, "second": {} if second_order else None}
    with one_blas_thread():  # small products: a second BLAS thread only costs (benchmarks/sensitivity_speed.py)
        for u in selected:
            _unknown(cb.fields[u], u, random, rows, batch, patterns, time_nodes, second_order, out)
    return SensitivityResult(inputs=[c.name for c in inputs], time=None if tc is None else tc.name, times=times_,
                             at=fixed, densities=described, second=out["second"],
                             seconds=_time.perf_counter() - start, unknowns=selected,
                             **{k: out[k] for k in ("mean", "variance", "first", "total")})
