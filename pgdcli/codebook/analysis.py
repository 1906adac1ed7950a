"""What a codebook answers besides its values: event times, series, derivatives, nodal grids, Sobol
indices, labelled grids.

:class:`CodebookAnalysis` is the half of :class:`~pgdcli.codebook.Codebook`'s interface built
on its evaluation (the bases, the domain checks, the fields): each method checks the request
and hands the numbers to :mod:`~pgdcli.codebook.series`, :mod:`~pgdcli.codebook.gradient`,
:mod:`~pgdcli.codebook.sensitivity` or :mod:`~pgdcli.codebook.notebook`. numpy only.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ..errors import QueryError
from .events import event_times, event_without_time
from .gradient import gradient_grid, gradient_points
from .notebook import to_xarray
from .sensitivity import sensitivity
from .series import evaluate_series

__all__ = ["CodebookAnalysis"]


class CodebookAnalysis:
    """Event times, series, gradients, nodal grids, sensitivity and xarray views of a codebook.

    A base of :class:`~pgdcli.codebook.Codebook`, which provides ``coordinates``, ``fields``,
    the bases and the domain checks these methods use.
    """

    def with_events(self, events: Mapping[str, "EventTime"]) -> "Codebook":
        """The same codebook with these events (its fields, spec and report shared, not copied)."""
        return type(self)(self.coordinates, self.fields, name=self.name, spec_text=self.spec_text, report=self.report,
                        description=self.description, created=self.created, partial=self.partial,
                        format_version=self.format_version, events=events)

    def event_times(self, coordinates: Mapping[str, object], events: Sequence[str] | None = None
                    ) -> dict[str, np.ndarray]:
        """Event name -> its time at points given for every coordinate but time (broadcast together); all
        events by default. See :func:`pgdcli.codebook.events.event_times` (QueryError on bad input)."""
        if self._event_book is None:  # each event on its own nodes: a codebook of its own
            self._event_book = {e: type(self)(ev.coordinates, {e: ev.field}, name=self.name)
                                for e, ev in self.events.items()}
        return event_times(self, self._event_book, coordinates, events)

    def event_codebook(self, name: str) -> "Codebook":
        """The time of event ``name`` as a codebook of its own, for export: the coordinates but time, one
        unknown named ``name``, the time core contracted at the start (the field is constant in time).

        Raises
        ------
        QueryError
            No event of that name.
        """
        if name not in self.events:
            known = ", ".join(self.events) or "none"
            raise QueryError(f"unknown event {name!r}; this codebook's events: {known}")
        event = self.events[name]
        coords, train = event_without_time(event)
        return type(self)(coords, {name: train}, name=f"{self.name}_{name}", description=f"time of {event.when}")

    def evaluate_series(self, points: Mapping[str, object], series: Mapping[str, object],
                        fields: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Unknowns at every one of ``S`` points in all coordinates but one, for each of ``T`` values
        of that one (a time series per parameter point).

        The values of :meth:`evaluate` at ``{c: points[c][:, None]} | {t: series[t][None, :]}``
        (equal to rounding), with the cores (modes) of the other coordinates contracted once per
        point and the series coordinate's for all its values by one matrix product
        (:mod:`pgdcli.codebook.series`).

        Parameters
        ----------
        points : mapping
            Every coordinate but the series one -> scalar or 1-D array_like (broadcast together,
            length ``S``; no coordinates besides the series one: ``S = 1``).
        series : mapping
            The series coordinate -> 1-D array_like of its ``T`` values (one entry).
        fields : sequence of str, optional
            Unknowns (default: all, in declared order).

        Returns
        -------
        dict of str to ndarray
            Unknown name -> values of shape ``(S, T)``.

        Raises
        ------
        QueryError
            Not exactly one series coordinate, missing, unknown or out-of-domain coordinates,
            unknown fields.
        """
        if len(series) != 1:
            raise QueryError(f"a series runs along one coordinate, got {len(series)}: {', '.join(series) or 'none'}")
        along = next(iter(series))
        self._check_names({**points, along: None})
        if along in points:
            raise QueryError(f"coordinate {along!r} is given both as the series and among the points")
        selected = self._select(fields)
        j = self._names.index(along)
        values = np.asarray(series[along], dtype=float)
        if values.ndim > 1:
            raise QueryError(f"coordinate {along!r}: a series must be 1-D, got shape {values.shape}")
        others = [c for c in self.coordinates if c.name != along]
        arrays = np.broadcast_arrays(*[np.asarray(points[c.name], dtype=float) for c in others]) if others else []
        if any(a.ndim > 1 for a in arrays):
            raise QueryError(f"the points of a series must be 1-D, got shape {arrays[0].shape}")
        mats = [None] * len(self.coordinates)
        for c, a in zip(others, arrays):
            k = self._names.index(c.name)
            mats[k] = self._bases[k].interpolation_matrix(self._checked(c, a.reshape(-1)))
        rows = self._bases[j].series_rows(self._checked(self.coordinates[j], values.reshape(-1)))
        return evaluate_series(self.fields, mats, j, rows, selected)

    def gradient(self, coordinates: Mapping[str, object], wrt: Sequence[str] | None = None,
                 fields: Sequence[str] | None = None, grid: bool = False) -> dict[str, dict[str, np.ndarray]]:
        """Derivatives of unknowns with respect to coordinates (exact derivatives of the interpolants).

        Parameters
        ----------
        coordinates : mapping
            As in :meth:`evaluate` (broadcast points) or, with ``grid=True``, as in
            :meth:`evaluate_grid` (1-D axes of a cartesian grid).
        wrt : sequence of str, optional
            Coordinates to differentiate with respect to (default: all).
        fields : sequence of str, optional
            Unknowns (default: all).
        grid : bool
            Whether ``coordinates`` are grid axes (default: points).

        Returns
        -------
        dict of str to dict of str to ndarray
            ``out[u][c]``: d u / d c, shaped like :meth:`evaluate`'s (or :meth:`evaluate_grid`'s) values.
            Where the interpolant has a kink (a slab breakpoint, a linear element's node) the derivative
            is the one from the right (at the upper end: from the left). See :mod:`pgdcli.codebook.gradient`.

        Raises
        ------
        QueryError
            Missing, unknown or out-of-domain coordinates, an unknown name in ``wrt`` or ``fields``.
        """
        self._check_names(coordinates)
        wrt = list(self._names if wrt is None else wrt)
        for w in wrt:
            if w not in self._name_set:
                raise QueryError(f"unknown coordinate {w!r} in wrt; this codebook has {', '.join(self._names)}")
        index = [self._names.index(w) for w in wrt]
        selected = self._select(fields)
        if grid:
            axes = [self._checked(c, np.asarray(coordinates[c.name], dtype=float).reshape(-1)) for c in self.coordinates]
            raw = gradient_grid(self.fields, self._bases, axes, index, selected)
            return {u: dict(zip(wrt, raw[u])) for u in selected}
        arrays = np.broadcast_arrays(*[np.asarray(coordinates[n], dtype=float) for n in self._names])
        shape = arrays[0].shape
        flat = [self._checked(c, a.reshape(-1)) for c, a in zip(self.coordinates, arrays)]
        raw = gradient_points(self.fields, self._bases, flat, index, selected)
        return {u: {w: v.reshape(shape) for w, v in zip(wrt, raw[u])} for u in selected}

    def nodal_values(self, field_name: str) -> np.ndarray:
        """An unknown on the full tensor grid of nodes (small codebooks only: tests and plots).

        Parameters
        ----------
        field_name : str
            The unknown.

        Returns
        -------
        ndarray, shape (n_1, ..., n_d)
            Its values at every node, coordinates in dimension order (``n_k`` nodes of the k-th).

        Raises
        ------
        QueryError
            No unknown has that name.
        """
        return self.fields[self._select([field_name])[0]].full()

    def sensitivity(self, *, times=None, at: Mapping[str, float] | None = None, densities: Mapping | None = None,
                    second_order: bool = False, fields: Sequence[str] | None = None):
        """Means, variances and Sobol indices over the parameters (``pgd sensitivity``).

        Every coordinate that is neither time nor in ``at`` is an independent random input,
        uniform over its domain unless ``densities`` says otherwise (``{"k": "normal:2,0.3"}``).
        Exact for the codebook's function: one-dimensional quadratures contracted through the
        modes or cores, no sampling. See :func:`pgdcli.codebook.sensitivity.sensitivity`.

        Returns
        -------
        SensitivityResult
            ``mean[u]``, ``variance[u]`` (T,), ``first[u]``, ``total[u]`` (T, inputs), ``second[u]``
            (T, inputs, inputs) when asked, ``inputs``, ``times``.
        """
        return sensitivity(self, times=times, at=at, densities=densities, second_order=second_order, fields=fields)

    def to_xarray(self, axes: Mapping[str, object] | None = None, /, *, fields: Sequence[str] | None = None,
                  **coordinates):
        """The unknowns on a grid as a labelled ``xarray.Dataset`` (xarray: ``pip install 'pgdcli[xarray]'``).

        Parameters
        ----------
        axes : mapping, optional
            Coordinate name -> values (or give them as keywords: ``cb.to_xarray(t=ts, k=[1, 2], c=0.3)``).
            Every coordinate is needed. A sequence (even of one value) is a dimension; a scalar holds
            the coordinate there and is a scalar coordinate of the Dataset, not a dimension.
        fields : sequence of str, optional
            Unknowns (default all): the Dataset's variables.

        Returns
        -------
        xarray.Dataset
            Variables: the unknowns over the dimensions (codebook order). Coordinates carry their
            role, domain, nodes and discretization as attributes; the Dataset carries the name,
            description, tolerance, relative_tolerance, measured_error (max abs against the
            independent reference), measured_points and accurate (1 within tolerance, 0 written
            with --keep-inaccurate, -1 not measured).
        """
        return to_xarray(self, {**dict(axes or {}), **coordinates}, fields=fields)
