"""Evaluation of a codebook's fields: one point, batches of points, cartesian grids.

Every path interpolates each mode (or core) with its coordinate's own basis, so a query at
the nodes returns the nodal values exactly:

- one point given as numbers: :class:`~pgdcli.codebook.point_weights.PointData` weights per coordinate,
  the CP modes of all unknowns side by side, the tensor trains through
  :class:`~pgdcli.codebook.point.TTStack`;
- a batch: CP unknowns chunk by chunk (:meth:`Evaluator.cp_batch`), tensor trains core by core
  (:class:`~pgdcli.codebook.batch_eval.TTBatch`), both under the thread/BLAS policy of
  :mod:`pgdcli.codebook.threads`;
- a grid: coordinate by coordinate (:func:`grid_tt`, :func:`grid_cp`).

:func:`contract_tt` is the plain row-wise contraction of a tensor train at points: the
reference the fast paths are tested against, and what the derivatives
(:mod:`pgdcli.codebook.gradient`) use with derivative rows in one coordinate's place.
numpy only (the query path); the batch module is imported on the first batch.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ..discretization.coordinates import CoordinateInfo
from .batch_eval import TTBatch
from .fields import TT, CPTensor
from .point import TTStack
from .point_weights import PointData
from .threads import batch_blas, chunk_bounds, chunk_length, run_chunks

__all__ = ["Evaluator", "shared_basis", "contract_tt", "grid_tt", "grid_cp"]

_dot, _multiply = np.dot, np.multiply
_basis_cache: dict = {}


def shared_basis(c: CoordinateInfo):
    """The (immutable, shared) basis of a coordinate: built once per process."""
    key = (c.discretization, float(c.domain[0]), float(c.domain[1]), int(c.nodes), tuple(c.breakpoints))
    basis = _basis_cache.get(key)
    if basis is None:
        if len(_basis_cache) >= 256:
            _basis_cache.clear()
        basis = _basis_cache.setdefault(key, c.basis())
    return basis


class Evaluator:
    """What a codebook precomputes to evaluate its fields (the fields themselves are not copied).

    Parameters
    ----------
    coordinates : sequence of CoordinateInfo
    fields : mapping
        Unknown name -> :class:`CPTensor` or :class:`TT` (validated by the caller).

    Attributes
    ----------
    bases : list
        Per coordinate, its basis.
    stacked : list of ndarray or None
        Per coordinate, the CP unknowns' modes side by side, shape (nodes_j, total CP rank)
        (None without CP unknowns): one interpolation per coordinate serves every unknown.
    slices : dict
        CP unknown -> its columns in ``stacked``.
    tt_stack : TTStack or None
        The tensor trains of the first train's core order, for one point.
    tt_all : TTStack or None
        ``tt_stack`` when it holds every unknown in their order (one point then skips the bookkeeping).
    """

    def __init__(self, coordinates: Sequence[CoordinateInfo], fields: Mapping):
        self.fields = fields
        self.bases = [shared_basis(c) for c in coordinates]
        cp = {u: fm for u, fm in fields.items() if isinstance(fm, CPTensor)}
        self.stacked = [np.hstack([fm.factors[j] for fm in cp.values()]) if cp else None
                        for j in range(len(self.bases))]
        bounds = np.cumsum([0] + [fm.rank for fm in cp.values()])
        self.slices = {u: slice(bounds[i], bounds[i + 1]) for i, u in enumerate(cp)}
        self.points = [PointData(c, b, m) for c, b, m in zip(coordinates, self.bases, self.stacked)]
        self.tt_stack = TTStack.build(fields, self.points)
        stack = self.tt_stack
        self.tt_all = stack if stack is not None and stack.names == list(fields) else None
        self._tt_batch = None  # batch_eval.TTBatch, built on the first batch of tensor-train points

    # ------------------------------------------------------------------ one point
    def rows(self, xs: list[float]) -> list[np.ndarray]:
        """Cardinal rows (a unit row at a node) of one point, coordinate by coordinate."""
        return [p.row(p.clipped(x)) for x, p in zip(xs, self.points)]

    def tt_point(self, xs: list[float]) -> dict[str, np.ndarray]:
        """Every unknown at one point when :attr:`tt_all` holds them all (0-d arrays)."""
        stack = self.tt_all
        return dict(zip(stack.names, map(np.array, stack.at_point(xs))))

    def point(self, xs: list[float], selected: list[str], shape: tuple) -> dict[str, np.ndarray]:
        """One point: per coordinate, its cardinal row times its modes (CP); tensor trains: :meth:`TTStack.at_point`.

        For CP unknowns the same arithmetic, in the same order, as the batch path on one point.
        """
        rows = None
        out = {}
        if any(u in self.slices for u in selected):
            rows = self.rows(xs)
            product = None
            for row, p in zip(rows, self.points):
                # np.dot: the gemv of `row @ modes` with less call overhead (for vector . vector it is
                # not the same routine as `@`, whose rounding of zeros the last step keeps)
                vals = _dot(row, p.modes)  # (total rank,)
                product = vals if product is None else _multiply(product, vals, out=product)
            for u in selected:
                if u in self.slices:
                    out[u] = np.array(product[self.slices[u]] @ self.fields[u].weights)
        stack = self.tt_stack
        if stack is not None and any(u in stack.index for u in selected):
            values = stack.at_point(xs)
            for u in selected:
                if u in stack.index:
                    out[u] = np.array(values[stack.index[u]])
        for u in selected:
            if u not in out:  # a tensor train outside the common stack (other core order)
                rows = self.rows(xs) if rows is None else rows
                out[u] = np.array(contract_tt(self.fields[u], [r[None, :] for r in rows])[0])
        if shape == ():
            return {u: out[u] for u in selected}
        return {u: out[u].reshape(shape) for u in selected}

    # ------------------------------------------------------------------ batches
    def cp_batch(self, flat: list[np.ndarray], selected: list[str]) -> dict[str, np.ndarray]:
        """CP unknowns at the points ``flat[j][i]`` (one checked array per coordinate, same length, not 1).

        Chunk by chunk (:func:`~pgdcli.codebook.threads.chunk_length` points): per coordinate
        the cardinal rows times the stacked modes of every unknown, their product over
        coordinates, times each unknown's weights.
        """
        bases, stacked, slices = self.bases, self.stacked, self.slices
        size = flat[0].size
        out = {u: np.empty(size) for u in selected}
        if size == 0:
            return out
        rank = stacked[0].shape[1]
        chunk = min(size, chunk_length(rank, max(b.size for b in bases)))
        term_weights = {u: self.fields[u].weights for u in selected}

        def run(bounds):
            rows = chunk + 1  # the last chunk may hold one more point (see chunk_bounds)
            prod = np.empty((rows, rank))
            vals = np.empty((rows, rank))
            scratch = [(np.empty((rows, b.size)), np.empty((rows, b.size))) for b in bases]
            for lo, hi in bounds:
                m = hi - lo
                p = prod[:m]
                for j, (basis, modes, x, (weights, work)) in enumerate(zip(bases, stacked, flat, scratch)):
                    w = basis.interpolation_rows(x[lo:hi], weights[:m], work[:m])
                    if j == 0:
                        np.matmul(w, modes, out=p)
                    else:
                        np.multiply(p, np.matmul(w, modes, out=vals[:m]), out=p)
                for u in selected:
                    np.matmul(p[:, slices[u]], term_weights[u], out=out[u][lo:hi])

        run_chunks(run, chunk_bounds(size, chunk))
        return out

    def tt_batch(self, flat: list[np.ndarray], selected: list[str]) -> dict[str, np.ndarray]:
        """Tensor-train unknowns at the points ``flat[j][i]`` (:class:`~pgdcli.codebook.batch_eval.TTBatch`)."""
        if self._tt_batch is None:  # prepared on the first batch (pgd query of one point never needs it)
            trains = {u: f for u, f in self.fields.items() if isinstance(f, TT)}
            self._tt_batch = TTBatch(trains, self.bases)
        # the CP path's BLAS and thread policy (one BLAS thread, blocks shared by our threads)
        return self._tt_batch.evaluate(flat, selected, run_chunks)

    # ------------------------------------------------------------------ grids
    def grid(self, values: list[np.ndarray], selected: list[str]) -> dict[str, np.ndarray]:
        """Unknowns on the cartesian grid of checked per-coordinate ``values`` (none empty).

        Under the batches' BLAS policy (one BLAS thread from BLAS_LIMIT_MIN_POINTS grid points):
        threaded BLAS on a loaded machine made grids of the high-dimensional codebooks many times
        slower, the first call most (``benchmarks/query_speed_tt.py``'s grid rows).
        """
        mats = [b.interpolation_matrix(v) for b, v in zip(self.bases, values)]
        with batch_blas(int(np.prod([v.size for v in values], dtype=float))):
            return {u: grid_tt(self.fields[u], mats) if isinstance(self.fields[u], TT) else
                    grid_cp(self.fields[u], mats) for u in selected}


def contract_tt(fm: TT, mats: list[np.ndarray]) -> np.ndarray:
    """Tensor train at points: ``mats[j]`` (P, nodes_j) are the points' rows per coordinate; shape (P,).

    The rows are cardinal rows for values, or a derivative's rows in one coordinate's place.
    """
    v = None
    for core, j in zip(fm.cores, fm.mode_order):
        r0, n, r1 = core.shape
        if v is None:
            v = mats[j] @ core[0]  # (P, r1)
        else:
            # row-wise Khatri-Rao product of the running contraction and the rows,
            # then one matrix product with the unfolded core
            kr = (v[:, :, None] * mats[j][:, None, :]).reshape(v.shape[0], r0 * n)
            v = kr @ core.reshape(r0 * n, r1)
    return v[:, 0]


def grid_tt(fm: TT, mats: list[np.ndarray]) -> np.ndarray:
    """Tensor train on the grid of the points behind ``mats[j]`` (P_j, nodes_j): shape (P_1, ..., P_d).

    Contracted from both ends toward one core (the pivot, :func:`_pivot`): the running blocks
    (points so far, r) times the unfolded cores, each new coordinate's rows applied to the node
    axis. A grid with one long axis (a trajectory over time at one parameter point) pivots on
    that axis and costs one vector-core product per other core; a grid whose largest cores sit in
    the middle of the train (the rigid body) pivots at the end: the points pile up after those cores.
    """
    cores, order = fm.cores, fm.mode_order
    sizes = [mats[j].shape[0] for j in order]
    k = _pivot(cores, sizes)
    left = np.ones((1, 1))  # (points of cores < k, r)
    for core, j in zip(cores[:k], order[:k]):
        r0, n, r1 = core.shape
        partial = (left @ core.reshape(r0, n * r1)).reshape(left.shape[0], n, r1)
        left = np.matmul(mats[j], partial).reshape(-1, r1)
    right = np.ones((1, 1))  # (r, points of cores > k), the later cores' points varying fastest
    for core, j in zip(cores[:k:-1], order[:k:-1]):
        r0, n, r1 = core.shape
        partial = (core.reshape(r0 * n, r1) @ right).reshape(r0, n, -1)  # (r0, n, points so far)
        right = np.matmul(mats[j], partial).reshape(r0, -1)  # (r0, P_j x points so far)
    middle = np.tensordot(mats[order[k]], cores[k], axes=(1, 1))  # (P_k, r0, r1)
    block = np.matmul(np.matmul(left, middle), right)  # (P_k, left points, right points)
    block = np.moveaxis(block, 0, 1).reshape(sizes)
    return np.transpose(block, np.argsort(order))


def _pivot(cores, sizes: list[int]) -> int:
    """The core :func:`grid_tt` contracts toward: the least multiply-adds by the model
    ``sum_i (points before core i on its side) n_i r0_i r1_i`` plus the pivot's own products."""
    d = len(cores)
    shapes = [c.shape for c in cores]
    before = np.cumprod([1] + sizes[:-1])  # points piled up left of core i
    after = np.cumprod(([1] + sizes[::-1])[:-1])[::-1]  # ... right of core i
    work = [r0 * n * r1 for r0, n, r1 in shapes]
    costs = []
    for k in range(d):
        r0, n, r1 = shapes[k]
        cost = sum(before[i] * work[i] for i in range(k)) + sum(after[i] * work[i] for i in range(k + 1, d))
        cost += sizes[k] * (n * r0 * r1 + before[k] * r0 * r1 + before[k] * r1 * after[k])
        costs.append(cost)
    return int(np.argmin(costs))


def grid_cp(fm: CPTensor, mats: list[np.ndarray]) -> np.ndarray:
    """CP field on the grid of the points behind ``mats[j]`` (P_j, nodes_j): shape (P_1, ..., P_d).

    ``sum_r alpha_r prod_j V_j[:, r]`` with ``V_j`` the interpolated modes: the product over
    every coordinate but the one with most points is formed as a (points, rank) block, and one
    matrix product with that coordinate's ``V`` finishes the sum over the rank.
    """
    vs = [m @ modes for m, modes in zip(mats, fm.factors)]  # (P_j, rank)
    last = int(np.argmax([v.shape[0] for v in vs]))
    block = fm.weights[None, :]
    for j, v in enumerate(vs):
        if j != last:
            block = (block[:, None, :] * v[None, :, :]).reshape(-1, v.shape[1])
    sizes = [v.shape[0] for j, v in enumerate(vs) if j != last]
    grid = (block @ vs[last].T).reshape(sizes + [vs[last].shape[0]])  # the longest axis last
    return np.moveaxis(grid, -1, last)

