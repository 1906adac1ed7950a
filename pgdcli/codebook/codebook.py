"""Codebooks: evaluation of separated solutions and their HDF5 files.

A codebook holds, for every unknown ``u``, a separated representation

    u(x_1, ..., x_d) = sum_i alpha_i  U_i1(x_1) * ... * U_id(x_d)

with the modes stored by their values at the nodes of each coordinate's
basis, plus the problem spec and the solver report. Evaluation interpolates
each mode with its basis's own interpolant (barycentric for Chebyshev,
piecewise linear for linear elements), so a query at the nodes returns the
nodal values exactly.

The file layout is documented in ``docs/codebook-format.md``. This module is
on the query path: it imports numpy and h5py only (no scipy, no yaml).
"""

from __future__ import annotations

import datetime as _dt
import os
import threading
from bisect import bisect_right
from typing import Mapping, Sequence

import numpy as np

from ..discretization.coordinates import CoordinateInfo
from ..errors import CodebookError, QueryError
from . import io as codebook_io
from .fields import FieldModes, FieldTT, validate_field
from .io import FORMAT_NAME, FORMAT_VERSION

__all__ = ["InaccurateCodebookWarning", "Codebook", "CoordinateInfo", "FieldModes", "FieldTT", "FORMAT_NAME", "FORMAT_VERSION"]


class InaccurateCodebookWarning(UserWarning):
    """A codebook loaded from a file marked as missing its tolerance (``pgd solve --keep-inaccurate``)."""


# ----------------------------------------------------------------------------------------------
# evaluation machinery (measurements: benchmarks/README.md)
# ----------------------------------------------------------------------------------------------
# Batches are evaluated in chunks of points whose working set (two (chunk, total rank) blocks and
# two (chunk, nodes) blocks per coordinate) stays within a few MiB of cache. A batch of at most one
# chunk makes exactly the numpy/BLAS calls of the unchunked algorithm, so its values are bitwise
# those of pgdcli <= 0.1.0. Larger batches: chunk lengths are multiples of _ROW_ALIGN, so every
# row keeps its position in the row blocks of the BLAS kernels; the kernel a product takes still
# depends on its shape (small-matrix kernels), so for some (nodes, rank) shapes a value can differ
# in the last bit from the unchunked product over all points -- as that product's own values
# depend on the number of points. One point takes a matrix-vector path (as before).
# Measured (spring, 2 cores): one thread is as fast with 448-point chunks (1 MiB) as with 2000
# (4 MiB), but two threads scale only with the larger ones (1.5e6 -> 2.2e6 points/s), which hold
# the GIL for a smaller share of their time.
_ROW_ALIGN = 64
_CHUNK_BYTES = 1 << 22
_MAX_CHUNK = 4096
# BLAS thread policy per call site (measured: benchmarks/README.md).
# - One point, and batches under _BLAS_LIMIT_MIN_POINTS: BLAS as is. A one-row product is far
#   below OpenBLAS's threading threshold, small batches cost little either way, and `pgd query`
#   on a few points is spared the threadpoolctl import (~10 ms).
# - Larger batches: BLAS limited to one thread (threadpoolctl) while they run. Threaded BLAS is at
#   best ~1.2x faster on these skinny products on idle cores, and many times slower when another
#   process holds a core (its threads spin waiting for each other): 1000 points took 16 ms
#   instead of 1 ms, 1e5 points ran at 0.06e6 points/s.
# - From _PARALLEL_MIN_POINTS: chunks shared by up to _MAX_THREADS threads of our own (numpy and
#   BLAS release the GIL): ~1.7x on 2 idle cores; a few % slower when the cores are busy.
_BLAS_LIMIT_MIN_POINTS = 512
_PARALLEL_MIN_POINTS = 16384
_MAX_THREADS = 8
# One-point tensor trains: cores with up to this many values per node (all unknowns) go through
# their node table (see _TTStack); the gemv's output then fits the first-level cache (32 KiB).
_ROW_FIRST_MAX = 4096
_PAIR_MAX = 1 << 20  # values in the merged table of the first two cores (8 MiB)
_SCALAR_TYPES = frozenset({float, int, np.float64})
_add_reduce, _dot, _matmul, _multiply = np.add.reduce, np.dot, np.matmul, np.multiply
_blas_lock = threading.Lock()
_blas_controller = None  # threadpoolctl.ThreadpoolController, built on first use; False: unavailable
_blas_limiter = None  # the active one-thread limit, shared by the batches running (_blas_users)
_blas_users = 0
_basis_cache: dict = {}


def _basis(c: CoordinateInfo):
    """The (immutable, shared) basis of a coordinate: built once per process."""
    key = (c.discretization, float(c.domain[0]), float(c.domain[1]), int(c.nodes), tuple(c.breakpoints))
    basis = _basis_cache.get(key)
    if basis is None:
        if len(_basis_cache) >= 256:
            _basis_cache.clear()
        basis = _basis_cache.setdefault(key, c.basis())
    return basis


class _PointData:
    """Constants of one coordinate for the one-point path of :meth:`Codebook.evaluate`."""

    __slots__ = ("name", "domain", "low", "high", "lower", "upper", "chebyshev", "nodes", "node_list",
                 "node_index", "bary", "unit", "modes", "basis", "piecewise", "breaks", "slab", "slab_nodes",
                 "bounds")

    def __init__(self, c: CoordinateInfo, basis, modes: np.ndarray):
        low, high = c.domain
        slack = 1e-12 * max(1.0, abs(low), abs(high))  # as Codebook._checked
        self.name, self.domain = c.name, c.domain
        self.low, self.high = float(low), float(high)
        self.lower, self.upper = low - slack, high + slack
        self.chebyshev = basis.kind == "chebyshev"
        self.nodes = basis.nodes
        self.node_list = basis.nodes.tolist()
        self.node_index = {v: k for k, v in enumerate(self.node_list)}
        self.bary = getattr(basis, "bary", None)
        self.unit = np.eye(basis.size)
        self.modes = modes
        self.basis = basis
        self.piecewise = bool(getattr(basis, "slab_size", 0))
        self.breaks = list(getattr(basis, "breakpoints", ()))[1:-1]  # interior breakpoints
        self.slab = int(getattr(basis, "slab_size", 0))
        # each slab's nodes as its own array: a point's slab costs a list lookup, not a slice
        self.slab_nodes = [basis.nodes[s * (self.slab - 1): s * (self.slab - 1) + self.slab]
                           for s in range(len(self.breaks) + 1)] if self.piecewise else []
        self.bounds = self.window_bounds()

    def clipped(self, x: float) -> float:
        """``x`` checked against the domain (with its slack) and clipped into it, as the batch path."""
        if not (x >= self.lower and x <= self.upper):
            raise _outside(self, x)
        x = x if x > self.low else self.low
        return x if x < self.high else self.high

    def row(self, x: float) -> np.ndarray:
        """The cardinal row (a unit row at a node) of the clipped value ``x``, shape (nodes,)."""
        k, c = self.weights(x)
        if c is None:
            return self.unit[k]
        if self.chebyshev and not self.piecewise:
            return c / _add_reduce(c)
        lo, hi = self.bounds[k]
        row = np.zeros(self.nodes.size)
        row[lo:hi] = c / _add_reduce(c) if self.piecewise else c  # linear: (1 - theta, theta) as they are
        return row

    def windows(self, table: np.ndarray) -> list[np.ndarray]:
        """The row blocks of ``table`` (one row per node) that :meth:`weights` selects.

        One block for a Chebyshev coordinate, one per slab for a piecewise one,
        one per element (two nodes) for a linear one. Row slices of a C-ordered
        table: contiguous views, so BLAS takes them as they are.
        """
        return [table[lo:hi] for lo, hi in self.window_bounds()]

    def window_bounds(self) -> list[tuple[int, int]]:
        """Node ranges ``(lo, hi)`` of the windows (see :meth:`windows`)."""
        if self.piecewise:
            step = self.slab - 1
            return [(s * step, s * step + self.slab) for s in range(len(self.slab_nodes))]
        if self.chebyshev:
            return [(0, len(self.node_list))]
        return [(k, k + 2) for k in range(len(self.node_list) - 1)]

    def weights(self, x: float) -> tuple[int, np.ndarray | None]:
        """Interpolation weights of the clipped value ``x``, not divided by their sum.

        Returns
        -------
        (k, None)
            ``x`` is node ``k`` (its row is the unit row ``k``).
        (k, c)
            The row is ``c / c.sum()`` on the nodes of window ``k`` of :meth:`windows`
            (barycentric weights ``bary / (x - nodes)``, or ``(1 - theta, theta)``).
            The caller divides once by the product of the sums over all coordinates,
            which saves a reduction and a division per coordinate.
        """
        k = self.node_index.get(x)
        if k is not None:
            return k, None
        if self.piecewise:  # the slab of x (a breakpoint is a node: handled above)
            s = bisect_right(self.breaks, x)
            return s, self.bary / (x - self.slab_nodes[s])
        if self.chebyshev:
            return 0, self.bary / (x - self.nodes)
        nodes = self.node_list
        left = min(max(bisect_right(nodes, x) - 1, 0), len(nodes) - 2)
        theta = (x - nodes[left]) / (nodes[left + 1] - nodes[left])
        return left, np.array((1.0 - theta, theta))


class _TTStack:
    """The tensor-train unknowns that share a core order, zero-padded to common ranks.

    One point costs one BLAS call and one batched product per core for all
    those unknowns at once (padding with zeros leaves every product unchanged).
    Most cores are kept as a table with one row per node: the stacked slices
    ``G[:, :, x_k, :]`` of every unknown, flattened to ``q r0 r1`` values, and a
    last column of ones. The point's weights times (a window of) the table give
    every unknown's interpolated core slice and, in the last column, the sum of
    the weights; the slices are chained by one batched product. Cores of more
    than ``_ROW_FIRST_MAX`` slice values are contracted with the running vector
    first instead (``(q, 1, r0) @ (q, r0, n r1)``): that product's output stays
    in the first-level cache, where the table's would not (measured: a (74, 8, 63)
    core of 6 unknowns took 33 us that way, 44 us through the table).

    The first two cores are merged into one table (see :meth:`_pair`) when the
    first coordinate's window (a time slab: 6-8 nodes) is narrower than the
    bond between them: fewer flops and one product less (coupled: 4.5 -> 2.5 us).
    """

    def __init__(self, names: list[str], cores: list[np.ndarray], order: tuple[int, ...], points: Sequence):
        self.names = names
        self.index = {u: i for i, u in enumerate(names)}
        self.order = order
        self.pair = None
        if len(cores) > 1 and self._merges(cores[0], cores[1], points[order[0]]):
            self.pair = self._pair(order[0], order[1], cores[0], cores[1], points)
            order, cores = order[2:], cores[2:]
        # per core: (coordinate index, through the table?, rows by node, windows, slice shape)
        self.cores = [self._table(j, core, points[j]) if (k == 0 and self.pair is None)
                      or core.size <= _ROW_FIRST_MAX * core.shape[2] else self._vector_first(j, core, points[j])
                      for k, (j, core) in enumerate(zip(order, cores))]

    @staticmethod
    def _table(j: int, core: np.ndarray, point: _PointData) -> tuple:
        q, r0, n, r1 = core.shape
        table = np.empty((n, q * r0 * r1 + 1))
        table[:, :-1] = core.transpose(2, 0, 1, 3).reshape(n, -1)
        table[:, -1] = 1.0  # the weights' sum
        return j, True, table, point.windows(table), (q, r0, r1)

    @staticmethod
    def _vector_first(j: int, core: np.ndarray, point: _PointData) -> tuple:
        q, r0, n, r1 = core.shape
        core = np.ascontiguousarray(core)
        by_node = [core[:, :, k, :] for k in range(n)]  # strided (q, r0, r1) views: BLAS takes them
        windows = []
        for lo, hi in point.window_bounds():
            windows.append((core[:, :, lo:hi, :].reshape(q, r0, (hi - lo) * r1), (q, hi - lo, r1)))
        return j, False, by_node, windows, None

    @staticmethod
    def _merges(first: np.ndarray, second: np.ndarray, point: _PointData) -> bool:
        """Whether the first two cores are cheaper merged: per point ``w n2 q r2`` multiply-adds
        instead of ``w q r1 + n2 q r1 r2`` (w: the first coordinate's window) and one product less."""
        q, _, n1, r1 = first.shape
        _, _, n2, r2 = second.shape
        width = max(hi - lo for lo, hi in point.window_bounds())
        return width < r1 and n2 * (q * r2 + 1) <= _ROW_FIRST_MAX and n1 * n2 * (q * r2 + 1) <= _PAIR_MAX

    @staticmethod
    def _pair(j1: int, j2: int, first: np.ndarray, second: np.ndarray, points: Sequence) -> tuple:
        """The first two cores as one table: row ``k1`` holds, for every node ``k2`` of the second
        coordinate, the stacked ``G1[:, 0, k1, :] G2[:, :, k2, :]`` (``q r2`` values) and a one."""
        q, _, n1, _ = first.shape
        _, _, n2, r2 = second.shape
        table = np.empty((n1, n2, q * r2 + 1))
        table[:, :, :-1] = np.einsum("iar,irbs->abis", first[:, 0], second).reshape(n1, n2, q * r2)
        table[:, :, -1] = 1.0  # the first weights' sum, then (second gemv) the product of both sums
        table = table.reshape(n1, -1)
        return (j1, j2, table, points[j1].windows(table), points[j2].window_bounds(), (n2, q * r2 + 1),
                (q, 1, r2))

    def _at_pair(self, weights: list) -> tuple[np.ndarray, float]:
        """The running vector (q, 1, r2) after the merged first two cores, and its scale."""
        j1, j2, table, windows, bounds, middle, shape = self.pair
        k, c = weights[j1]
        row = (table[k] if c is None else _dot(c, windows[k])).reshape(middle)  # (n2, q r2 + 1)
        k, c = weights[j2]
        if c is None:
            row = row[k]
        else:
            lo, hi = bounds[k]
            row = _dot(c, row[lo:hi])
        return row[:-1].reshape(shape), row[-1]

    def at_point(self, weights: list) -> list[float]:
        """Values of the stacked unknowns at one point (``weights``: :meth:`_PointData.weights` per coordinate)."""
        v, scale = (None, 1.0) if self.pair is None else self._at_pair(weights)
        for j, through_table, rows, windows, shape in self.cores:
            k, c = weights[j]
            if through_table:
                row = rows[k] if c is None else _dot(c, windows[k])  # the core slice at x, and sum(c)
                scale *= row[-1]
                g = row[:-1].reshape(shape)  # (q, r0, r1)
                v = g if v is None else _matmul(v, g)  # (q, 1, r1)
            elif c is None:
                v = _matmul(v, rows[k])
            else:
                window, shape = windows[k]
                scale *= _add_reduce(c)
                v = _matmul(c[None, :], _matmul(v, window).reshape(shape))  # (1, w) @ (q, w, r1)
        scale = float(scale)
        return [value / scale for value in v.reshape(-1).tolist()]


    @classmethod
    def build(cls, fields: Mapping, points: Sequence) -> "_TTStack | None":
        tts = {u: f for u, f in fields.items() if isinstance(f, FieldTT)}
        if not tts:
            return None
        order = next(iter(tts.values())).mode_order
        names = [u for u, f in tts.items() if f.mode_order == order]
        d = len(order)
        ranks = [1] + [max(tts[u].cores[k].shape[2] for u in names) for k in range(d - 1)] + [1]
        cores = []
        for k in range(d):
            n = tts[names[0]].cores[k].shape[1]
            stack = np.zeros((len(names), ranks[k], n, ranks[k + 1]))
            for i, u in enumerate(names):
                c = tts[u].cores[k]
                stack[i, : c.shape[0], :, : c.shape[2]] = c
            cores.append(stack)
        return cls(names, cores, order, points)


def _outside(p: _PointData, x: float) -> QueryError:
    """The out-of-domain error of one point (the batch path's message)."""
    low, high = p.domain
    return QueryError(f"coordinate {p.name!r}: value {x!r} is outside the domain [{low:g}, {high:g}]")


def _chunk_length(rank: int, nodes: int) -> int:
    rows = _CHUNK_BYTES // (16 * (rank + nodes))
    return min(_MAX_CHUNK, max(_ROW_ALIGN, rows // _ROW_ALIGN * _ROW_ALIGN))


def _chunk_bounds(size: int, chunk: int) -> list[tuple[int, int]]:
    """``[lo, hi)`` ranges of ``chunk`` points covering ``range(size)``; a last range of one point
    joins the one before (a one-row product would take a matrix-vector path)."""
    edges = list(range(0, size, chunk)) + [size]
    if len(edges) > 2 and edges[-1] - edges[-2] == 1:
        del edges[-2]
    return list(zip(edges[:-1], edges[1:]))


def _threads() -> int:
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    return max(1, min(n, _MAX_THREADS))


def _run_chunks(run, bounds: list[tuple[int, int]]) -> None:
    """``run(iterator of bounds)``, with the BLAS and thread policy above."""
    size = bounds[-1][1]
    if size < _BLAS_LIMIT_MIN_POINTS or not _limit_blas():
        run(iter(bounds))
        return
    try:
        threads = min(_threads(), len(bounds)) if size >= _PARALLEL_MIN_POINTS else 1
        if threads <= 1:
            run(iter(bounds))
            return
        todo = iter(bounds)  # shared: a thread takes the next chunk when it is done with one
        errors = []

        def guarded():
            try:
                run(todo)
            except BaseException as exc:  # re-raised in the calling thread
                errors.append(exc)

        workers = [threading.Thread(target=guarded, daemon=True) for _ in range(threads - 1)]
        for w in workers:
            w.start()
        guarded()
        for w in workers:
            w.join()
        if errors:
            raise errors[0]
    finally:
        _unlimit_blas()


def _limit_blas() -> bool:
    """Limit BLAS to one thread (process-wide) until the matching :func:`_unlimit_blas`.

    Batches running at the same time share one limit, lifted when the last one
    ends. False (and no limit) if threadpoolctl is unavailable.
    """
    global _blas_controller, _blas_limiter, _blas_users
    with _blas_lock:
        if _blas_controller is None:
            try:
                from threadpoolctl import ThreadpoolController

                _blas_controller = ThreadpoolController()
            except Exception:  # pragma: no cover - threadpoolctl is a dependency
                _blas_controller = False
        if not _blas_controller:  # pragma: no cover
            return False
        if _blas_users == 0:
            _blas_limiter = _blas_controller.limit(limits=1, user_api="blas")
            _release_blas_control()
        _blas_users += 1
        return True


def _unlimit_blas() -> None:
    global _blas_limiter, _blas_users
    with _blas_lock:
        _blas_users -= 1
        if _blas_users == 0:
            _blas_limiter.restore_original_limits()
            _blas_limiter = None
            _release_blas_control()


def _release_blas_control() -> None:
    """Let any thread set OpenBLAS's (process-wide) limit next time.

    threadpoolctl >= 3.8 hands that limit to the first thread that sets it and
    silently ignores every other thread until the owner clears it; the limit
    here is shared by the batches running and set or lifted, under
    ``_blas_lock``, by whichever thread comes first or ends last. Without this a
    batch run from a worker thread after one from the main thread ran with
    BLAS unlimited (and values differing in the last bit).
    """
    import threadpoolctl  # imported by _limit_blas already

    clear = getattr(getattr(threadpoolctl, "OpenBLASController", None), "clear_controlling_thread", None)
    if clear is not None:
        clear(force=True)


class Codebook:
    """A separated solution that evaluates anywhere in its domain.

    Parameters
    ----------
    coordinates : sequence of CoordinateInfo
        In dimension order.
    fields : mapping
        Unknown name -> :class:`FieldModes`, in output order.
    name : str
    spec_text : str
        The YAML spec the codebook was solved from.
    report : dict
        Solver report (see ``docs/codebook-format.md``).
    description : str

    Examples
    --------
    >>> cb = Codebook.load("codebooks/parametric.h5")      # doctest: +SKIP
    >>> cb(t=[0.0, 5.0], k=2.0)["u"]                        # doctest: +SKIP
    array([0., 20.])
    """

    def __init__(self, coordinates: Sequence[CoordinateInfo], fields: Mapping[str, FieldModes], *,
                 name: str = "codebook", spec_text: str = "", report: Mapping | None = None,
                 description: str = "", created: str | None = None):
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
        self.created = created or _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        self._bases = [_basis(c) for c in self.coordinates]
        # all unknowns' modes side by side: one interpolation per coordinate serves every unknown
        cp = {u: fm for u, fm in self.fields.items() if isinstance(fm, FieldModes)}
        self._stacked = [np.hstack([fm.modes[j] for fm in cp.values()]) if cp else None
                         for j in range(len(self.coordinates))]
        bounds = np.cumsum([0] + [fm.rank for fm in cp.values()])
        self._slices = {u: slice(bounds[i], bounds[i + 1]) for i, u in enumerate(cp)}
        self._names = tuple(c.name for c in self.coordinates)
        self._name_set = frozenset(self._names)
        self._point = [_PointData(c, b, m) for c, b, m in zip(self.coordinates, self._bases, self._stacked)]
        self._tt_stack = _TTStack.build(self.fields, self._point)
        # the stack, when it holds every unknown (in their order): one point then skips evaluate's bookkeeping
        stack = self._tt_stack
        self._tt_all = stack if stack is not None and stack.names == list(self.fields) else None
        self._tt_batch = None  # batch_eval.TTBatch, built on the first batch of tensor-train points

    # ------------------------------------------------------------------ introspection
    @property
    def coordinate_names(self) -> list[str]:
        return [c.name for c in self.coordinates]

    @property
    def unknown_names(self) -> list[str]:
        return list(self.fields)

    def coordinate(self, name: str) -> CoordinateInfo:
        for c in self.coordinates:
            if c.name == name:
                return c
        raise QueryError(f"unknown coordinate {name!r}; this codebook has {', '.join(self.coordinate_names)}")

    def __repr__(self) -> str:
        coords = ", ".join(f"{c.name}=[{c.domain[0]:g}, {c.domain[1]:g}]" for c in self.coordinates)
        ranks = ", ".join(f"{u}: {fm.rank}" for u, fm in self.fields.items())
        return f"<Codebook {self.name!r} coordinates ({coords}) modes ({ranks})>"

    # ------------------------------------------------------------------ evaluation
    def __call__(self, **coordinates) -> dict[str, np.ndarray]:
        """Evaluate every unknown; see :meth:`evaluate`."""
        return self.evaluate(coordinates)

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
        dict
            Unknown name -> ndarray of the broadcast shape (0-d for scalars).

        Raises
        ------
        QueryError
            Missing, unknown or out-of-domain coordinates, unknown fields.
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
        if not scalars and any(isinstance(self.fields[u], FieldTT) for u in selected):
            return self._evaluate_mixed(coordinates, selected)
        if scalars:
            # one point given as Python numbers: a handful of small numpy calls, no broadcasting
            return self._evaluate_point([float(v) for v in raw], selected, ())
        arrays = np.broadcast_arrays(*[np.asarray(v, dtype=float) for v in raw])
        shape = arrays[0].shape
        if arrays[0].size == 1:
            return self._evaluate_point([float(a.reshape(-1)[0]) for a in arrays], selected, shape)
        flat = [self._checked(c, a.reshape(-1)) for c, a in zip(self.coordinates, arrays)]
        values = self._evaluate_flat(flat, selected)
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
        dict
            Unknown name -> ndarray of shape ``(len(axes[c_1]), ..., len(axes[c_d]))``, the
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
        mats = [b.interpolation_matrix(v) for b, v in zip(self._bases, values)]
        return {u: _grid_tt(self.fields[u], mats) if isinstance(self.fields[u], FieldTT) else
                _grid_cp(self.fields[u], mats) for u in selected}

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
        dict
            ``out[u][c]``: d u / d c, shaped like :meth:`evaluate`'s (or :meth:`evaluate_grid`'s) values.
            Where the interpolant has a kink (a slab breakpoint, a linear element's node) the derivative
            is the one from the right (at the upper end: from the left). See :mod:`pgdcli.codebook.gradient`.
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

        The one-point path without its bookkeeping (a few microseconds of a ~15 us
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
        stack = self._tt_all
        values = stack.at_point(self._point_weights(list(map(float, raw))))
        return dict(zip(stack.names, map(np.array, values)))

    def _evaluate_mixed(self, coordinates: Mapping[str, object], selected: list[str]) -> dict[str, np.ndarray]:
        """Tensor-train unknowns (and any CP ones beside them)."""
        tt = [u for u in selected if isinstance(self.fields[u], FieldTT)]
        cp = [u for u in selected if u not in tt]
        out = self.evaluate(coordinates, cp) if cp else {}
        arrays = np.broadcast_arrays(*[np.asarray(coordinates[c.name], dtype=float) for c in self.coordinates])
        shape = arrays[0].shape
        flat = [self._checked(c, a.reshape(-1)) for c, a in zip(self.coordinates, arrays)]
        if self._tt_batch is None:  # prepared on the first batch (pgd query of one point never needs it)
            from .batch_eval import TTBatch

            self._tt_batch = TTBatch({u: f for u, f in self.fields.items() if isinstance(f, FieldTT)}, self._bases)
        # the CP path's BLAS and thread policy (one BLAS thread, blocks shared by our threads)
        values = self._tt_batch.evaluate(flat, tt, _run_chunks)
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

    def _point_rows(self, xs: list[float]) -> list[np.ndarray]:
        """Cardinal rows (a unit row at a node) of one point, coordinate by coordinate."""
        return [p.row(p.clipped(x)) for x, p in zip(xs, self._point)]

    def _point_weights(self, xs: list[float]) -> list[tuple]:
        """:meth:`_PointData.weights` of one point, coordinate by coordinate (checked and clipped as rows)."""
        return [p.weights(p.clipped(x)) for x, p in zip(xs, self._point)]

    def _evaluate_point(self, xs: list[float], selected: list[str], shape: tuple) -> dict[str, np.ndarray]:
        """One point: per coordinate, its cardinal row times its modes (CP); tensor trains: :meth:`_TTStack.at_point`.

        For CP unknowns the same arithmetic, in the same order, as the batch path on one point.
        """
        rows = None
        out = {}
        if any(u in self._slices for u in selected):
            rows = self._point_rows(xs)
            product = None
            for row, p in zip(rows, self._point):
                # np.dot: the gemv of `row @ modes` with less call overhead (for vector . vector it is
                # not the same routine as `@`, whose rounding of zeros the last step keeps)
                vals = _dot(row, p.modes)  # (total rank,)
                product = vals if product is None else _multiply(product, vals, out=product)
            for u in selected:
                if u in self._slices:
                    out[u] = np.array(product[self._slices[u]] @ self.fields[u].alphas)
        stack = self._tt_stack
        if stack is not None and any(u in stack.index for u in selected):
            values = stack.at_point(self._point_weights(xs))
            for u in selected:
                if u in stack.index:
                    out[u] = np.array(values[stack.index[u]])
        for u in selected:
            if u not in out:  # a tensor train outside the common stack (other core order)
                rows = self._point_rows(xs) if rows is None else rows
                mats = [r[None, :] for r in rows]
                out[u] = np.array(_contract_tt(self.fields[u], mats)[0])
        if shape == ():
            return {u: out[u] for u in selected}
        return {u: out[u].reshape(shape) for u in selected}

    def _evaluate_flat(self, flat: list[np.ndarray], selected: list[str]) -> dict[str, np.ndarray]:
        """Evaluate at the points ``flat[j][i]`` (one array per coordinate, same length, not 1).

        Chunk by chunk (:func:`_chunk_length` points, see the notes above it): per
        coordinate the cardinal rows times the stacked modes of every unknown, their
        product over coordinates, times each unknown's alphas.
        """
        bases, stacked, slices = self._bases, self._stacked, self._slices
        size = flat[0].size
        out = {u: np.empty(size) for u in selected}
        if size == 0:
            return out
        rank = stacked[0].shape[1]
        chunk = min(size, _chunk_length(rank, max(b.size for b in bases)))
        alphas = {u: self.fields[u].alphas for u in selected}

        def run(bounds):
            rows = chunk + 1  # the last chunk may hold one more point (see _chunk_bounds)
            prod = np.empty((rows, rank))
            vals = np.empty((rows, rank))
            scratch = [(np.empty((rows, b.size)), np.empty((rows, b.size))) for b in bases]
            for lo, hi in bounds:
                m = hi - lo
                p = prod[:m]
                for j, (basis, modes, x, (weights, work)) in enumerate(zip(bases, stacked, flat, scratch)):
                    w = basis._interpolation_rows(x[lo:hi], weights[:m], work[:m])
                    if j == 0:
                        np.matmul(w, modes, out=p)
                    else:
                        np.multiply(p, np.matmul(w, modes, out=vals[:m]), out=p)
                for u in selected:
                    np.matmul(p[:, slices[u]], alphas[u], out=out[u][lo:hi])

        _run_chunks(run, _chunk_bounds(size, chunk))
        return out

    def nodal_values(self, field_name: str) -> np.ndarray:
        """The unknown on the full tensor grid of nodes (small codebooks only: tests and plots)."""
        fm = self.fields[self._select([field_name])[0]]
        if isinstance(fm, FieldTT):
            full = fm.cores[0][0]
            for core in fm.cores[1:]:
                full = np.tensordot(full, core, axes=(-1, 0))
            return np.transpose(full[..., 0], np.argsort(fm.mode_order))
        out = np.zeros(tuple(c.nodes for c in self.coordinates))
        letters = "abcdefghijklmnopqrstuvwxyz"[: len(self.coordinates)]
        expr = ",".join(f"{l}r" for l in letters) + ",r->" + letters
        out += np.einsum(expr, *fm.modes, fm.alphas)
        return out

    @property
    def accurate(self) -> bool | None:
        """True: the measured error met the tolerance; False: written anyway (``--keep-inaccurate``);
        None: not measured (an older codebook, or a reference that could not run)."""
        value = self.report.get("accurate")
        if value is None or int(value) < 0:
            return None
        return bool(int(value))

    def nodes_chosen(self) -> dict | None:
        """The automatic resolution's solves: ``{"automatic": [names], "reason": str, "rounds": [{"nodes":
        {coordinate: nodes}, "ratio": measured error / tolerance}]}``; None for a codebook without it."""
        rep = self.report
        if "resolution_rounds" not in rep:
            return None
        rounds = np.asarray(rep["resolution_rounds"], dtype=float)
        auto = [n for n in str(rep.get("resolution_auto", "")).split(",") if n]
        return {"automatic": auto, "reason": str(rep.get("resolution_reason", "")),
                "rounds": [{"nodes": {c: int(n) for c, n in zip(self.coordinate_names, row[:-1])},
                            "ratio": float(row[-1]) if np.isfinite(row[-1]) else None} for row in rounds]}

    # ------------------------------------------------------------------ summary
    def info(self, path: str | os.PathLike | None = None) -> dict:
        """Summary as plain Python data (what ``pgd info`` prints)."""
        rep = self.report
        out = {
            "name": self.name,
            "description": self.description,
            "format": f"{FORMAT_NAME} {FORMAT_VERSION}",
            "created": self.created,
            "coordinates": [
                {"name": c.name, "role": c.role, "domain": [c.domain[0], c.domain[1]], "nodes": c.nodes,
                 "discretization": c.discretization,
                 **({"elements": len(c.breakpoints) - 1} if c.breakpoints and c.role != "time" else {})}
                for c in self.coordinates
            ],
            "unknowns": {u: _field_summary(fm) for u, fm in self.fields.items()},
            "method": str(rep.get("method", "pgd")),
            "converged": bool(rep.get("converged", False)),
            "accurate": self.accurate,
            "relative_tolerance": float(rep.get("relative_tolerance", 0.0)),
            "residual": float(rep.get("residual", np.nan)),
            "tolerance": float(rep.get("tolerance", np.nan)),
            "solve_time": float(rep.get("wall_time", np.nan)),
            "pgdcli_version": str(rep.get("pgdcli_version", "")),
        }
        if "roundings_exact" in rep:
            out["roundings"] = {k: int(rep[f"roundings_{k}"]) for k in ("exact", "sketched", "redone")}
        if "crosses" in rep:  # functions of the unknowns, by cross approximation (pgdcli.algorithms.general_rhs)
            out["crosses"] = {"count": int(rep["crosses"]), "not_converged": int(rep["crosses_not_converged"]),
                              "evaluations": int(rep["cross_evaluations"]), "max_rank": int(rep["cross_max_rank"]),
                              "failure": str(rep["cross_failure"])}
        if "check_error" in rep:
            def finite(key):  # JSON has no NaN: an unchecked march gives None
                v = float(rep[key])
                return v if np.isfinite(v) else None

            out["check"] = {"error": finite("check_error"), "node_error": finite("check_node_error"),
                            "between_error": finite("check_between_error"), "points": int(rep["check_points"]),
                            "failed": int(rep["check_failed"]), "where": str(rep["check_where"])}
            for key, name in (("check_ratio", "ratio"), ("march_tolerance", "march_tolerance")):
                if key in rep:
                    out["check"][name] = finite(key)
            if "check_method" in rep:
                out["check"]["method"] = str(rep["check_method"])
        if "resolution_rounds" in rep:
            out["nodes_chosen"] = self.nodes_chosen()
        if "rates" in rep:  # {rate unknown: the unknown it is the time derivative of}
            out["rates"] = dict(pair.split("=", 1) for pair in str(rep["rates"]).split(",") if "=" in pair)
        if "separated_coefficients" in rep:  # how many terms each non-separable coefficient needed
            out["separated_coefficients"] = [line for line in str(rep["separated_coefficients"]).split("; ") if line]
        if "resolution" in rep and "resolution_coordinates" in rep:
            names = str(rep["resolution_coordinates"]).split(",")
            table = np.asarray(rep["resolution"], dtype=float)
            out["resolution"] = {u: {c: (float(v) if np.isfinite(v) else None) for c, v in zip(names, row)}
                                 for u, row in zip(self.unknown_names, table)}
        if path is not None:
            out["size_bytes"] = os.path.getsize(path)
        return out

    # ------------------------------------------------------------------ I/O (pgdcli.codebook.io)
    def save(self, path: str | os.PathLike) -> "os.PathLike":
        """Write the codebook to ``path`` atomically (temporary file + rename).

        A crash or error while writing leaves any previous file at ``path``
        untouched and no partial file behind.
        """
        return codebook_io.save(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Codebook":
        """Read a codebook file.

        Raises
        ------
        CodebookError
            The file is missing, not HDF5, truncated, not a codebook, of an
            unknown major version, or inconsistent.
        """
        cb = cls(**codebook_io.load_parts(path, _basis))
        if cb.accurate is False:
            import warnings

            warnings.warn(f"{path}: this codebook misses its tolerance ({cb.report.get('message', '')}); it was "
                          f"written with --keep-inaccurate", InaccurateCodebookWarning, stacklevel=2)
        return cb


def _field_summary(fm) -> dict:
    if isinstance(fm, FieldTT):
        return {"representation": "tensor-train", "modes": fm.rank, "ranks": list(fm.ranks), "floats": fm.size}
    return {"representation": "cp", "modes": fm.rank, "floats": int(fm.alphas.size + sum(m.size for m in fm.modes))}


def _contract_tt(fm: FieldTT, mats: list[np.ndarray]) -> np.ndarray:
    """Tensor train at points: ``mats[j]`` (P, nodes_j) are the cardinal rows per coordinate."""
    v = None
    for core, j in zip(fm.cores, fm.mode_order):
        r0, n, r1 = core.shape
        if v is None:
            v = mats[j] @ core[0]  # (P, r1)
        else:
            # row-wise Khatri-Rao product of the running contraction and the cardinal rows,
            # then one matrix product with the unfolded core
            kr = (v[:, :, None] * mats[j][:, None, :]).reshape(v.shape[0], r0 * n)
            v = kr @ core.reshape(r0 * n, r1)
    return v[:, 0]


def _grid_tt(fm: FieldTT, mats: list[np.ndarray]) -> np.ndarray:
    """Tensor train on the grid of the points behind ``mats[j]`` (P_j, nodes_j): shape (P_1, ..., P_d).

    Core by core along the train: the running block (points so far, r) times the unfolded
    core, then the new coordinate's cardinal rows applied to the node axis; the grid comes
    out in the train's core order and is transposed to coordinate order.
    """
    block = np.ones((1, 1))  # (points of the cores so far, r_k)
    sizes = []
    for core, j in zip(fm.cores, fm.mode_order):
        r0, n, r1 = core.shape
        partial = (block @ core.reshape(r0, n * r1)).reshape(block.shape[0], n, r1)
        block = np.matmul(mats[j], partial).reshape(-1, r1)  # (points so far x P_j, r1)
        sizes.append(mats[j].shape[0])
    return np.transpose(block.reshape(sizes), np.argsort(fm.mode_order))


def _grid_cp(fm: FieldModes, mats: list[np.ndarray]) -> np.ndarray:
    """CP field on the grid of the points behind ``mats[j]`` (P_j, nodes_j): shape (P_1, ..., P_d).

    ``sum_r alpha_r prod_j V_j[:, r]`` with ``V_j`` the interpolated modes: the product over
    every coordinate but the one with most points is formed as a (points, rank) block, and one
    matrix product with that coordinate's ``V`` finishes the sum over the rank.
    """
    vs = [m @ modes for m, modes in zip(mats, fm.modes)]  # (P_j, rank)
    last = int(np.argmax([v.shape[0] for v in vs]))
    block = fm.alphas[None, :]
    for j, v in enumerate(vs):
        if j != last:
            block = (block[:, None, :] * v[None, :, :]).reshape(-1, v.shape[1])
    sizes = [v.shape[0] for j, v in enumerate(vs) if j != last]
    grid = (block @ vs[last].T).reshape(sizes + [vs[last].shape[0]])  # the longest axis last
    return np.moveaxis(grid, -1, last)
