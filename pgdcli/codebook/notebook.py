"""A codebook in notebooks and labelled arrays: ``Codebook.to_xarray`` and ``Codebook._repr_html_``.

Axes convention (one for every labelled result): a coordinate given as a scalar is held at that
value and is not an axis (a scalar coordinate of the Dataset); one given as a sequence, even of one
value, is an axis. :meth:`Codebook.evaluate_grid` keeps every coordinate as an axis (a scalar is an
axis of length 1): its shape is predictable from the codebook alone; :func:`to_xarray` then drops
the scalar ones, as ``Dataset.sel(t=0.5)`` would.

xarray is an optional dependency (``pip install pgdcli[xarray]``), imported on the first call.
"""

from __future__ import annotations

import html
import math
from typing import Mapping, Sequence

import numpy as np

from ..errors import PgdError
from .fields import TT

__all__ = ["to_xarray", "summary_html"]


def to_xarray(cb, axes: Mapping[str, object], fields: Sequence[str] | None = None):
    """The unknowns on the grid of ``axes`` as an ``xarray.Dataset`` (see :meth:`Codebook.to_xarray`)."""
    try:
        import xarray as xr
    except ImportError:
        raise PgdError("Codebook.to_xarray needs xarray: pip install 'pgdcli[xarray]'") from None
    scalar = {name: np.ndim(v) == 0 for name, v in axes.items()}
    grid = cb.evaluate_grid({k: (np.reshape(v, 1) if scalar[k] else v) for k, v in axes.items()}, fields=fields)
    names = cb.coordinate_names
    dims = [n for n in names if not scalar[n]]
    drop = tuple(k for k, n in enumerate(names) if scalar[n])
    coords = {}
    for c in cb.coordinates:
        attrs = {"role": c.role, "domain": np.array(c.domain, dtype=float), "nodes": int(c.nodes),
                 "discretization": c.discretization}
        value = np.asarray(axes[c.name], dtype=float)
        coords[c.name] = xr.Variable((), float(value), attrs) if scalar[c.name] else xr.Variable(c.name, value.reshape(-1),
                                                                                                   attrs)
    data = {u: xr.Variable(dims, np.squeeze(v, axis=drop) if drop else v) for u, v in grid.items()}
    report = cb.report
    attrs = {"name": cb.name, "description": cb.description, "created": cb.created,
             "tolerance": float(report.get("tolerance", np.nan)),
             "relative_tolerance": float(report.get("relative_tolerance", 0.0)),
             "accurate": int(report.get("accurate", -1)),
             "measured_error": float(report.get("check_error", np.nan)),
             "measured_points": int(report.get("check_points", 0)),
             "measured_where": str(report.get("check_where", "")),
             "source": "pgdcli codebook"}
    return xr.Dataset(data, coords=coords, attrs=attrs)


def _number(v, digits: int = 3) -> str:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return "n/a"
    return f"{v:.{digits}g}" if math.isfinite(v) else "n/a"


def summary_html(cb) -> str:
    """A summary card (HTML) of the codebook: what it is, its coordinates, unknowns and accuracy.

    Every string from the codebook is escaped.
    """
    e = html.escape
    report = cb.report
    rows = "".join(
        f"<tr><td>{e(c.name)}</td><td>{e(c.role)}</td><td>[{_number(c.domain[0], 6)}, {_number(c.domain[1], 6)}]</td>"
        f"<td>{int(c.nodes)}</td><td>{e(c.discretization)}</td></tr>" for c in cb.coordinates)
    unknowns = ", ".join(
        f"{e(u)} (tensor train, ranks {'-'.join(map(str, fm.ranks))})" if isinstance(fm, TT) else
        f"{e(u)} ({fm.rank} modes)" for u, fm in cb.fields.items())
    tolerance, error = _number(report.get("tolerance")), _number(report.get("check_error"))
    if cb.accurate is True:
        state = (f"<span style='color:#1a7f37'>within its tolerance {tolerance}</span>: measured max error {error} "
                 f"at {int(report.get('check_points', 0))} points")
    elif cb.accurate is False:
        state = (f"<span style='color:#b42318'>misses its tolerance {tolerance}</span> (measured {error}; written "
                 f"with --keep-inaccurate)")
    else:
        state = f"tolerance {tolerance}, error not measured"
    description = f"<div style='color:#5b6570'>{e(cb.description)}</div>" if cb.description else ""
    return (f"<div class='pgdcli-codebook' style='font-family:system-ui,sans-serif;font-size:13px;"
            f"border:1px solid #d8dde3;border-radius:6px;padding:8px 12px;display:inline-block'>"
            f"<div><b>Codebook {e(cb.name)}</b></div>{description}"
            f"<table style='border-collapse:collapse;margin:6px 0'><tr><th>coordinate</th><th>role</th>"
            f"<th>domain</th><th>nodes</th><th>basis</th></tr>{rows}</table>"
            f"<div>unknowns: {unknowns}</div><div>{state}</div></div>")
