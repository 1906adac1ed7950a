"""One comparison of a codebook with a reference: codebook values at the checked points, error figures.

Shared by ``pgd verify`` and the solve-time check. numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

__all__ = ["UnknownErrors", "codebook_at_samples", "codebook_on_space_grid", "error_statistics", "json_float"]


# codebook evaluations per block (bounds memory of the interpolation matrices)
_EVAL_BLOCK = 100_000


@dataclass
class UnknownErrors:
    """Error figures of one unknown over the compared points.

    NaN when no sample point could be integrated.

    Attributes
    ----------
    max_abs_error : float
        ``max |u_codebook - u_reference|``.
    max_rel_error : float
        ``max_abs_error / reference_scale`` (relative to the unknown's magnitude, not pointwise).
    rms_error : float
        Root-mean-square of ``u_codebook - u_reference``.
    reference_scale : float
        ``max |u_reference|``.
    where : dict of str to float
        Every coordinate (time included) of the largest absolute error.
    codebook_value, reference_value : float
        Both values at ``where``.
    tolerance_ratio : float
        ``max |u_codebook - u_reference| / (tolerance + relative_tolerance |u_reference|)`` for
        the codebook's own tolerance: at most 1 where the codebook keeps its promise (NaN when no
        tolerance was given).
    """

    max_abs_error: float
    max_rel_error: float
    rms_error: float
    reference_scale: float
    where: dict[str, float]
    codebook_value: float
    reference_value: float
    tolerance_ratio: float = float("nan")

    def to_dict(self) -> dict:
        return {
            "max_abs_error": json_float(self.max_abs_error),
            "max_rel_error": json_float(self.max_rel_error),
            "rms_error": json_float(self.rms_error),
            "reference_scale": json_float(self.reference_scale),
            "where": {k: json_float(v) for k, v in self.where.items()},
            "codebook_value": json_float(self.codebook_value),
            "reference_value": json_float(self.reference_value),
            "tolerance_ratio": json_float(self.tolerance_ratio),
        }


def codebook_at_samples(cb, samples: Mapping[str, np.ndarray], time: str | None, times: np.ndarray,
                        unknowns) -> dict:
    """Codebook values (S, T) at every sample (the parameters, ``samples[c]`` of length S) and every
    one of the ``times`` (T,); without a time coordinate (``time`` None) one value per sample,
    repeated T times.

    With a time coordinate: :meth:`~pgdcli.codebook.Codebook.evaluate_series`, the parameter cores
    contracted once per sample and the time core for all times by one matrix product (far faster
    than evaluating the broadcast points: ``benchmarks/query_speed_tt.py``), in blocks of samples.
    """
    S = len(next(iter(samples.values()))) if samples else 1
    T = times.size
    out = {u: np.empty((S, T)) for u in unknowns}
    series = time is not None and time in cb.coordinate_names
    block = max(1, _EVAL_BLOCK // max(T, 1))
    for start in range(0, S, block):
        rows = slice(start, min(S, start + block))
        if series:
            points = {c.name: samples[c.name][rows] for c in cb.coordinates if c.name != time}
            values = cb.evaluate_series(points, {time: times}, fields=list(unknowns))
        else:
            values = cb.evaluate({c.name: samples[c.name][rows, None] for c in cb.coordinates},
                                 fields=list(unknowns))
        for u in unknowns:
            out[u][rows] = np.broadcast_to(values[u], (rows.stop - rows.start, T))
    return out


def error_statistics(coordinates, time, samples, times, ok, reference, approx, space_points=None,
                     tolerance: float | None = None, relative_tolerance: float = 0.0) -> UnknownErrors:
    """Figures over the successful samples; values (S, T) or, with space coordinates, (S, T, X_1, ..., X_d)
    with the space axes in the order of ``space_points``. With ``tolerance`` (> 0), also the largest
    error over ``tolerance + relative_tolerance |reference|``."""
    if not ok.any():
        nan = float("nan")
        return UnknownErrors(nan, nan, nan, nan, {c: nan for c in coordinates}, nan, nan)
    space_points = space_points or {}
    ref = reference[ok]
    cbv = approx[ok]
    err = np.abs(cbv - ref)
    index = np.unravel_index(int(np.argmax(err)), err.shape)
    i, j = index[0], index[1]
    at_space = {c: float(points[k]) for (c, points), k in zip(space_points.items(), index[2:])}
    max_abs = float(err[index])
    scale = float(np.max(np.abs(ref)))
    if scale > 0:
        rel = max_abs / scale
    else:
        rel = 0.0 if max_abs == 0 else float("inf")
    rows = np.flatnonzero(ok)
    where = {c: float(times[j]) if c == time else at_space[c] if c in at_space else float(samples[c][rows[i]])
             for c in coordinates}
    ratio = float("nan")
    if tolerance is not None and tolerance > 0:
        ratio = float(np.max(err / (tolerance + relative_tolerance * np.abs(ref))))
    return UnknownErrors(
        max_abs_error=max_abs,
        max_rel_error=float(rel),
        rms_error=float(np.sqrt(np.mean(err**2))),
        reference_scale=scale,
        where=where,
        codebook_value=float(cbv[index]),
        reference_value=float(ref[index]),
        tolerance_ratio=ratio,
    )


def codebook_on_space_grid(cb, samples: Mapping[str, np.ndarray], S: int, time: str, times: np.ndarray,
                           space_points: Mapping[str, np.ndarray], unknowns) -> dict:
    """Codebook values (S, T, X_1, ..., X_d) on the tensor grid of the space points (a steady problem:
    ``time`` None and one placeholder time).

    Each sample's times x space points is one grid, evaluated coordinate by coordinate
    (:meth:`~pgdcli.codebook.Codebook.evaluate_grid`): orders of magnitude faster than as points.
    """
    space = list(space_points)
    shape = tuple(space_points[c].size for c in space)
    out = {u: np.empty((S, times.size) + shape) for u in unknowns}
    names = list(cb.coordinate_names)
    # from the codebook's coordinate order to (time, space...), the sample's axes (length 1) dropped
    order = ([names.index(time)] if time is not None else []) + [names.index(c) for c in space]
    for s in range(S):
        axes = {}
        for c in names:
            if c == time:
                axes[c] = times
            elif c in space_points:
                axes[c] = space_points[c]
            else:
                axes[c] = np.asarray(samples[c], dtype=float).reshape(-1)[s:s + 1]
        values = cb.evaluate_grid(axes, fields=list(unknowns))
        for u in unknowns:
            kept = np.transpose(values[u], order + [k for k in range(len(names)) if k not in order])
            out[u][s] = kept.reshape((times.size,) + shape)
    return out


def json_float(value: float) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None
