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
import warnings
from typing import Mapping, Sequence

import numpy as np

from ..discretization.coordinates import CoordinateInfo
from ..errors import CodebookError, QueryError
from . import io as codebook_io
from . import summary as codebook_summary
from .analysis import CodebookAnalysis
from .blockwise import evaluate_blockwise
from .domain import check_names, clip_to_domain, select_fields
from .evaluate import Evaluator, shared_basis
from .events import EventTime, validate_event
from .fields import TT, CPTensor, validate_field
from .io import FORMAT_NAME, FORMAT_VERSION
from .notebook import summary_html

__all__ = ["InaccurateCodebookWarning", "Codebook", "CoordinateInfo", "CPTensor", "TT", "FORMAT_NAME", "FORMAT_VERSION"]

_SCALAR_TYPES = frozenset({float, int, np.float64})


class InaccurateCodebookWarning(UserWarning):
    """A codebook loaded from a file marked as missing its tolerance (``pgd solve --keep-inaccurate``)."""


class Codebook(CodebookAnalysis):
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
    name, spec_text : str
        The problem's name; the YAML spec the codebook was solved from (``pgd info --spec`` prints it).
    report : dict
        Solver report: convergence, the measured error, tolerance, nodes chosen (see the
        codebook file format in the user guide).
    description, created : str
        The spec's description; the ISO 8601 time of the solve (default: now).
    partial : bool
        Loaded for evaluation only (``Codebook.load(path, evaluation_only=True)``): the spec and
        the report's arrays were not read, and :meth:`save` refuses it.
    format_version : str, optional
        The format of the file it was loaded from (``"1.0"`` files carry no checksums).
    events : mapping, optional
        Event name -> :class:`~pgdcli.codebook.events.EventTime` (``events:``; :meth:`event_times`).

    Raises
    ------
    CodebookError
        No coordinate or no unknown, or a field whose shapes do not match the coordinates.

    Attributes
    ----------
    coordinates : tuple of CoordinateInfo
    fields : dict of str to CPTensor or TT
    events : dict of str to EventTime
    name, spec_text, description, created : str
    report : dict

    Examples
    --------
    >>> cb = Codebook.load("codebooks/parametric.h5")      # doctest: +SKIP
    >>> cb(t=[0.0, 5.0], k=2.0)["u"]                        # doctest: +SKIP
    array([0., 20.])
    """

    phased_class = None  # the codebook of an event that acts, pgdcli.codebook.phases.PhasedCodebook

    def __init__(self, coordinates: Sequence[CoordinateInfo], fields: Mapping[str, CPTensor | TT], *,
                 name: str = "codebook", spec_text: str = "", report: Mapping | None = None,
                 description: str = "", created: str | None = None, partial: bool = False,
                 format_version: str | None = None, events: Mapping[str, EventTime] | None = None):
        self.coordinates = tuple(coordinates)
        if not self.coordinates:
            raise CodebookError("a codebook needs at least one coordinate")
        self.fields = dict(fields)
        if not self.fields:
            raise CodebookError("a codebook needs at least one unknown")
        for uname, fm in self.fields.items():
            validate_field(uname, self.coordinates, fm)
        self.events = {e: validate_event(e, self.coordinates, ev) for e, ev in (events or {}).items()}
        self._event_book = None  # each event's field as a codebook of its own, built when first asked
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
        attributes = ("name", "spec_text", "report", "description", "created", "partial", "format_version", "events")
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
        check_names(self.coordinates, given)

    def _select(self, fields: Sequence[str] | None) -> list[str]:
        return select_fields(self.unknown_names, fields)

    _checked = staticmethod(clip_to_domain)

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
        os.PathLike
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
            A :class:`~pgdcli.codebook.phases.PhasedCodebook` when the file has phases.

        Raises
        ------
        CodebookError
            The file is missing, not a regular file, not HDF5, truncated, not a codebook, of an unknown
            major version, not self-contained, too large, inconsistent or corrupted (phases included).
        """
        parts = codebook_io.load_parts(path, shared_basis, evaluation_only=evaluation_only)
        # an event that acts: phase 0 and its phases (the class registers itself: pgdcli.codebook.phases)
        cb = Codebook.phased_class.from_parts(parts, path) if "phases" in parts else cls(**parts)
        if cb.accurate is False:
            warnings.warn(f"{path}: this codebook misses its tolerance ({cb.report.get('message', '')}); it was "
                          f"written with --keep-inaccurate", InaccurateCodebookWarning, stacklevel=2)
        return cb


def _from_parts(coordinates, fields, attributes: dict) -> Codebook:
    """The codebook :meth:`Codebook.__reduce__` pickled."""
    return Codebook(coordinates, fields, **attributes)
