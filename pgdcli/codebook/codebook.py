"""Codebooks: evaluation of separated solutions and their HDF5 files.

A codebook holds, for every unknown ``u``, a separated representation

    u(x_1, ..., x_d) = sum_i alpha_i  U_i1(x_1) * ... * U_id(x_d)

(or a tensor train) with the modes stored by their values at the nodes of each coordinate's
basis, plus the problem spec and the solver report. Evaluation interpolates each mode with its
basis's own interpolant (barycentric for Chebyshev, piecewise linear for linear elements), so a
query at the nodes returns the nodal values exactly.

:class:`Codebook` is the facade: it checks names, domains and fields and hands the numbers to
:mod:`~pgdcli.codebook.evaluate` (one point, batches, grids; their thread/BLAS policy is
:mod:`~pgdcli.codebook.threads`), :mod:`~pgdcli.codebook.gradient` (derivatives),
:mod:`~pgdcli.codebook.io` (HDF5) and :mod:`~pgdcli.codebook.summary` (``pgd info``).

The file layout is documented in ``docs/codebook-format.md``. This module is
on the query path: it imports numpy and h5py only (no scipy, no yaml).
"""

from __future__ import annotations

import datetime as _dt
import os
from typing import Mapping, Sequence

import numpy as np

from ..discretization.coordinates import CoordinateInfo
from ..errors import CodebookError, QueryError
from . import io as codebook_io
from . import summary as codebook_summary
from .evaluate import Evaluator, shared_basis
from .fields import CPTensor, TT, validate_field
from .io import FORMAT_NAME, FORMAT_VERSION

__all__ = ["InaccurateCodebookWarning", "Codebook", "CoordinateInfo", "CPTensor", "TT", "FORMAT_NAME", "FORMAT_VERSION"]

_SCALAR_TYPES = frozenset({float, int, np.float64})


class InaccurateCodebookWarning(UserWarning):
    """A codebook loaded from a file marked as missing its tolerance (``pgd solve --keep-inaccurate``)."""


class Codebook:
    """A separated solution that evaluates anywhere in its domain.

    Usually made by :func:`pgdcli.solve` (``result.codebook``) or read by :meth:`load`; each
    unknown is stored either as a sum of products of one-coordinate modes (CP, from the PGD
    enrichment) or as a tensor train (from the time march).

    Parameters
    ----------
    coordinates : sequence of CoordinateInfo
        In dimension order: name, role (``time``, ``space`` or ``parameter``), domain, nodes and
        discretization of each.
    fields : mapping
        Unknown name -> :class:`~pgdcli.tensors.cp.CPTensor` (weights and one mode matrix of
        nodal values per coordinate) or :class:`~pgdcli.tensors.tt.TT` (cores with their
        ``mode_order``), in output order.
    name : str
        The problem's name.
    spec_text : str
        The YAML spec the codebook was solved from (``pgd info --spec`` prints it).
    report : dict
        Solver report: convergence, the measured error, tolerance, nodes chosen (see the
        codebook file format in the user guide).
    description : str
        The spec's description.
    created : str, optional
        ISO 8601 time of the solve (default: now).
    partial : bool
        Loaded for evaluation only (``Codebook.load(path, evaluation_only=True)``): the spec and
        the report's arrays were not read, and :meth:`save` refuses it.
    format_version : str, optional
        The format of the file it was loaded from (``"1.0"`` files carry no checksums).

    Raises
    ------
    CodebookError
        No coordinate or no unknown, or a field whose shapes do not match the coordinates.

    Attributes
    ----------
    coordinates : tuple of CoordinateInfo
    fields : dict of str to CPTensor or TT
    name, spec_text, description, created : str
    report : dict

    Examples
    --------
    >>> cb = Codebook.load("codebooks/parametric.h5")      # doctest: +SKIP
    >>> cb(t=[0.0, 5.0], k=2.0)["u"]                        # doctest: +SKIP
    array([0., 20.])
    """

    def __init__(self, coordinates: Sequence[CoordinateInfo], fields: Mapping[str, CPTensor | TT], *,
                 name: str = "codebook", spec_text: str = "", report: Mapping | None = None,
                 description: str = "", created: str | None = None, partial: bool = False,
                 format_version: str | None = None):
        self.coordinates = tuple(coordinates)
        if not self.coordinates:
            raise CodebookError("a codebook needs at least one coordinate")
        self.fields = dict(fields)
        if not self.fields:
            raise CodebookError("a codebook needs at least one unknown")
        for uname, fm in self.fields.items():
            validate_field(uname, self.coordinates, fm)
        self.name = name
        self.spec_text = spec_text
        self.description = description
        self.report = dict(report or {})
        self.partial = bool(partial)  # loaded for evaluation only: no spec, no report arrays
        self.format_version = format_version  # of the file it was loaded from (None: built in memory)
        self.created = created or _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        self._names = tuple(c.name for c in self.coordinates)
        self._name_set = frozenset(self._names)
        ev = self._evaluator = Evaluator(self.coordinates, self.fields)
        # the evaluator's state under the names the tests and benchmarks read
        self._bases, self._stacked, self._slices = ev.bases, ev.stacked, ev.slices
        self._tt_stack, self._tt_all = ev.tt_stack, ev.tt_all

    def __reduce__(self):
        """Pickled as its parts: the evaluator's tables, most of the bytes, are built again where it is
        unpickled (a Dask worker)."""
        attributes = ("name", "spec_text", "report", "description", "created", "partial", "format_version")
        return _from_parts, (self.coordinates, self.fields, {a: getattr(self, a) for a in attributes})

    # ------------------------------------------------------------------ introspection
    @property
    def coordinate_names(self) -> list[str]:
        """The coordinates' names, in dimension order."""
        return [c.name for c in self.coordinates]

    @property
    def unknown_names(self) -> list[str]:
        """The unknowns' names, in output order (second-order unknowns' rates last)."""
        return list(self.fields)

    def coordinate(self, name: str) -> CoordinateInfo:
        """The coordinate called ``name``.

        Parameters
        ----------
        name : str

        Returns
        -------
        CoordinateInfo
            Its role, domain, nodes and discretization; ``.basis()`` gives its 1-D basis.

        Raises
        ------
        QueryError
            No coordinate has that name.
        """
        for c in self.coordinates:
            if c.name == name:
                return c
        raise QueryError(f"unknown coordinate {name!r}; this codebook has {', '.join(self.coordinate_names)}")

    def __repr__(self) -> str:
        coords = ", ".join(f"{c.name}=[{c.domain[0]:g}, {c.domain[1]:g}]" for c in self.coordinates)
        ranks = ", ".join(f"{u}: {fm.rank}" for u, fm in self.fields.items())
        return f"<Codebook {self.name!r} coordinates ({coords}) modes ({ranks})>"

    def _repr_html_(self) -> str:
        """A summary card in notebooks (:func:`pgdcli.codebook.notebook.summary_html`)."""
        from .notebook import summary_html

        return summary_html(self)

    # ------------------------------------------------------------------ evaluation
    def __call__(self, points=None, /, **coordinates):
        """Evaluate every unknown: ``cb(t=..., k=...)`` as :meth:`evaluate`, or ``cb(points)``.

        Parameters
        ----------
        points : array_like, shape (..., d), optional
            Points as rows of their coordinates in codebook order (``coordinate_names``), as
            ``scipy.interpolate.RegularGridInterpolator`` takes them.
        **coordinates
            Or every coordinate name -> scalar or array_like (broadcast together).

        Returns
        -------
        ndarray, shape (..., n_unknowns)
            For ``points``: the unknowns in declared order (``unknown_names``) along the last axis.
        dict
            For keyword coordinates: unknown name -> ndarray of the broadcast shape (0-d for scalars).

        Axes: ``points`` and keyword arrays are points, not grids (no coordinate adds or drops an
        axis); :meth:`evaluate_grid` gives grids, with an axis for every coordinate, and
        :meth:`to_xarray` grids without the axes of coordinates given as scalars.
        """
        if points is None:
            return self.evaluate(coordinates)
        if coordinates:
            raise QueryError(f"give points as one (N, {len(self._names)}) array or coordinates as NAME=VALUE, not both")
        array = np.asarray(points, dtype=float)
        if array.ndim == 0 or array.shape[-1] != len(self._names):
            raise QueryError(f"points: expected an array of shape (..., {len(self._names)}) with the coordinates "
                             f"{', '.join(self._names)} in its last axis, got shape {array.shape}")
        values = self.evaluate({n: array[..., j] for j, n in enumerate(self._names)})
        out = np.empty(array.shape[:-1] + (len(values),))
        for k, v in enumerate(values.values()):
            out[..., k] = v
        return out

    def evaluate(self, coordinates: Mapping[str, object], fields: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Evaluate unknowns at points given per coordinate.

        Parameters
        ----------
        coordinates : mapping
            Every coordinate name -> scalar or array_like; the arrays are
            broadcast together with numpy rules.
        fields : sequence of str, optional
            Unknowns to evaluate (default: all, in declared order).

        Returns
        -------
        dict of str to ndarray
            Unknown name -> values of the broadcast shape (0-d for scalars); a dask array when a
            coordinate is one (evaluated block by block when computed, :mod:`pgdcli.codebook.blockwise`).

        Raises
        ------
        QueryError
            Missing, unknown or out-of-domain coordinates, unknown fields.

        Notes
        -----
        A point given as Python numbers takes the one-point path, the one ``pgd query`` uses
        (the same digits whichever way the point is asked); arrays take the batch path, whose
        last bits can differ with the shape of the batch.
        """
        if fields is None and self._tt_all is not None:
            values = self._tensor_train_point(coordinates)
            if values is not None:
                return values
        names = self._names
        if len(coordinates) != len(names) or not self._name_set.issuperset(coordinates):
            self._check_names(coordinates)
        selected = self._select(fields)
        raw = [coordinates[n] for n in names]
        scalars = all(type(v) in _SCALAR_TYPES for v in raw)
        if not scalars and any(hasattr(v, "__dask_graph__") for v in raw):  # a dask array: lazily, blockwise
            from .blockwise import evaluate_blockwise

            return evaluate_blockwise(self, dict(zip(names, raw)), selected)
        if not scalars and any(isinstance(self.fields[u], TT) for u in selected):
            return self._evaluate_mixed(coordinates, selected)
        if scalars:
            # one point given as Python numbers: a handful of small numpy calls, no broadcasting
            return self._evaluator.point([float(v) for v in raw], selected, ())
        arrays = np.broadcast_arrays(*[np.asarray(v, dtype=float) for v in raw])
        shape = arrays[0].shape
        if arrays[0].size == 1:
            return self._evaluator.point([float(a.reshape(-1)[0]) for a in arrays], selected, shape)
        flat = [self._checked(c, a.reshape(-1)) for c, a in zip(self.coordinates, arrays)]
        values = self._evaluator.cp_batch(flat, selected)
        return {u: v.reshape(shape) for u, v in values.items()}

    def evaluate_grid(self, axes: Mapping[str, object], fields: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Evaluate unknowns on the tensor grid of per-coordinate values (their cartesian product).

        The values of :meth:`evaluate` at ``np.meshgrid(*axes, indexing="ij")`` (equal to
        rounding), computed one coordinate at a time instead of point by point: each
        coordinate's values are interpolated once, and the separated form is contracted
        coordinate by coordinate, so the work per grid point is that of the last contraction
        (a tensor-train rank, or the CP rank) rather than of a whole point evaluation. On a
        grid of 10^5-10^6 points this is one to three orders of magnitude faster than
        :meth:`evaluate` on the flattened grid (``benchmarks/query_speed_tt.py``).

        Parameters
        ----------
        axes : mapping
            Every coordinate name -> 1-D array_like of values (a scalar is an axis of length 1).
        fields : sequence of str, optional
            Unknowns to evaluate (default: all, in declared order).

        Returns
        -------
        dict of str to ndarray
            Unknown name -> values of shape ``(len(axes[c_1]), ..., len(axes[c_d]))``, the
            coordinates in codebook order (``coordinate_names``), whatever the mapping's order.

        Raises
        ------
        QueryError
            Missing, unknown or out-of-domain coordinates, axes that are not 1-D, unknown fields.
        """
        self._check_names(axes)
        values = []
        for c in self.coordinates:
            x = np.asarray(axes[c.name], dtype=float)
            if x.ndim > 1:
                raise QueryError(f"coordinate {c.name!r}: a grid axis must be 1-D, got shape {x.shape}")
            values.append(self._checked(c, x.reshape(-1)))
        selected = self._select(fields)
        shape = tuple(v.size for v in values)
        if 0 in shape:
            return {u: np.empty(shape) for u in selected}
        return self._evaluator.grid(values, selected)

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
        from .series import evaluate_series

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
        rows = self._bases[j].interpolation_matrix(self._checked(self.coordinates[j], values.reshape(-1)))
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
        from .gradient import gradient_grid, gradient_points

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

    def _tensor_train_point(self, coordinates: Mapping[str, object]) -> dict[str, np.ndarray] | None:
        """Every unknown at one point given as Python numbers, when all are in the tensor-train stack.

        The one-point path without its bookkeeping (a sizeable share of a one-point
        query); None when the coordinates are anything else (the general path then
        decides, and raises what it raises).
        """
        names = self._names
        try:
            raw = [coordinates[n] for n in names]
        except KeyError:
            return None
        if len(coordinates) != len(names) or not _SCALAR_TYPES.issuperset(map(type, raw)):
            return None
        return self._evaluator.tt_point(list(map(float, raw)))

    def _evaluate_mixed(self, coordinates: Mapping[str, object], selected: list[str]) -> dict[str, np.ndarray]:
        """Tensor-train unknowns (and any CP ones beside them)."""
        tt = [u for u in selected if isinstance(self.fields[u], TT)]
        cp = [u for u in selected if u not in tt]
        out = self.evaluate(coordinates, cp) if cp else {}
        arrays = np.broadcast_arrays(*[np.asarray(coordinates[c.name], dtype=float) for c in self.coordinates])
        shape = arrays[0].shape
        flat = [self._checked(c, a.reshape(-1)) for c, a in zip(self.coordinates, arrays)]
        values = self._evaluator.tt_batch(flat, tt)
        out.update({u: v.reshape(shape) for u, v in values.items()})
        return {u: out[u] for u in selected}

    def _check_names(self, given: Mapping[str, object]) -> None:
        """Raise QueryError for the first unknown, then the first missing coordinate name."""
        names = self._names
        for key in given:
            if key not in names:
                raise QueryError(f"unknown coordinate {key!r}; this codebook has {', '.join(names)}")
        for c in self.coordinates:
            if c.name not in given:
                raise QueryError(f"missing coordinate {c.name!r} (domain [{c.domain[0]:g}, {c.domain[1]:g}])")

    def _select(self, fields: Sequence[str] | None) -> list[str]:
        if fields is None:
            return self.unknown_names
        out = []
        for f in fields:
            if f not in self.fields:
                raise QueryError(f"unknown field {f!r}; this codebook has {', '.join(self.unknown_names)}")
            out.append(f)
        return out

    @staticmethod
    def _checked(c: CoordinateInfo, x: np.ndarray) -> np.ndarray:
        low, high = c.domain
        slack = 1e-12 * max(1.0, abs(low), abs(high))  # rounding in user-side arithmetic (e.g. linspace)
        bad = ~((x >= low - slack) & (x <= high + slack))
        if bad.any():
            v = float(x[bad][0])
            raise QueryError(f"coordinate {c.name!r}: value {v!r} is outside the domain [{low:g}, {high:g}]")
        return np.clip(x, low, high)

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

    @property
    def accurate(self) -> bool | None:
        """True: the measured error met the tolerance; False: written anyway (``--keep-inaccurate``);
        None: not measured (an older codebook, or a reference that could not run)."""
        return codebook_summary.accurate(self.report)

    def nodes_chosen(self) -> dict | None:
        """The automatic resolution's solves.

        Returns
        -------
        dict or None
            ``{"automatic": [names], "reason": str, "rounds": [{"nodes": {coordinate: nodes},
            "ratio": measured error / tolerance}]}``; None for a codebook without it.
        """
        return codebook_summary.nodes_chosen(self.report, self.coordinate_names)

    # ------------------------------------------------------------------ analysis
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
        from .sensitivity import sensitivity

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
        from .notebook import to_xarray

        return to_xarray(self, {**dict(axes or {}), **coordinates}, fields=fields)

    # ------------------------------------------------------------------ summary
    def info(self, path: str | os.PathLike | None = None) -> dict:
        """Summary as plain Python data (what ``pgd info --format json`` prints).

        Parameters
        ----------
        path : path-like, optional
            The codebook's file, for its size (``size_bytes``).

        Returns
        -------
        dict
            Name, description, format, coordinates, unknowns (representation, modes or ranks),
            method, convergence, the measured error (``check``), tolerance, nodes chosen, solve
            time, and more: JSON-ready values only.

        Raises
        ------
        CodebookError
            A report entry of the wrong type (a file not written by pgdcli).
        """
        try:
            return codebook_summary.summary(self, path)
        except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
            where = f"{path}: " if path is not None else ""
            raise CodebookError(f"{where}corrupt codebook: its report cannot be read ({exc})") from None

    # ------------------------------------------------------------------ I/O (pgdcli.codebook.io)
    def save(self, path: str | os.PathLike) -> "os.PathLike":
        """Write the codebook to ``path`` atomically (temporary file + rename).

        A crash or error while writing leaves any previous file at ``path``
        untouched and no partial file behind.

        Parameters
        ----------
        path : path-like
            The HDF5 file to write (its folder must exist).

        Returns
        -------
        path-like
            The path written.
        """
        return codebook_io.save(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike, *, evaluation_only: bool = False) -> "Codebook":
        """Read a codebook file, checked before its data is read (``docs/codebook-format.md``).

        The file must be self-contained (no links to other files, no external storage), its
        arrays of the sizes its metadata implies and within ``PGD_MAX_CODEBOOK_BYTES``, and (format
        1.1) match their checksums and digests. A codebook written with ``pgd solve
        --keep-inaccurate`` loads with an :class:`InaccurateCodebookWarning`.

        Parameters
        ----------
        path : path-like
            An HDF5 file written by :meth:`save` (or ``pgd solve``).
        evaluation_only : bool
            Skip what evaluation does not need (the stored spec, the report's arrays).

        Returns
        -------
        Codebook

        Raises
        ------
        CodebookError
            The file is missing, not a regular file, not HDF5, truncated, not a codebook, of an
            unknown major version, not self-contained, too large, inconsistent or corrupted.
        """
        cb = cls(**codebook_io.load_parts(path, shared_basis, evaluation_only=evaluation_only))
        if cb.accurate is False:
            import warnings

            warnings.warn(f"{path}: this codebook misses its tolerance ({cb.report.get('message', '')}); it was "
                          f"written with --keep-inaccurate", InaccurateCodebookWarning, stacklevel=2)
        return cb


def _from_parts(coordinates, fields, attributes: dict) -> Codebook:
    """The codebook :meth:`Codebook.__reduce__` pickled."""
    return Codebook(coordinates, fields, **attributes)
