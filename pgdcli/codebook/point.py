"""One point through the tensor-train unknowns of a codebook: their stacked cores as tables.

A query of one point (``pgd query`` of a few points, a fit's residual) is dominated by call
overhead and by reading the cores, not flops: per coordinate its nodes, barycentric weights and
windows are precomputed (:class:`pgdcli.codebook.point_weights.PointData`) and the tensor-train
unknowns' cores laid out as contiguous tables (:class:`TTStack`), so a point costs one small BLAS
call and one batched product per core.
numpy only (the query path). Measurements: ``benchmarks/query_speed_tt.py`` (single-point rows).
"""

from __future__ import annotations

from operator import itemgetter
from typing import Mapping, Sequence

import numpy as np

from ..pages import huge_page_array
from ..tuning import HUGE_PAGES_ABOVE, PAIR_MAX, ROW_FIRST_MAX
from .fields import TT
from .point_weights import PointData, PointWeights

__all__ = ["TTStack"]

_add_reduce, _dot, _matmul = np.add.reduce, np.dot, np.matmul


class _Arena:
    """Arrays carved one after another out of one buffer, in huge pages when it is large.

    A point reads every table once; in 4 KiB pages their page walks cost a few per cent of a
    high-dimensional codebook's point. An array that no longer fits is an ordinary one.
    """

    def __init__(self, values: int):
        self.free = huge_page_array(values) if values * 8 > HUGE_PAGES_ABOVE else np.empty(0)

    def empty(self, shape: tuple) -> np.ndarray:
        size = int(np.prod(shape))
        if size > self.free.size:
            return np.empty(shape)
        out, self.free = self.free[:size].reshape(shape), self.free[size:]
        return out


class TTStack:
    """The tensor-train unknowns that share a core order, zero-padded to common ranks.

    One point costs one BLAS call and one batched product per core for all
    those unknowns at once (padding with zeros leaves every product unchanged).
    Most cores are kept as a table with one row per node: the stacked slices
    ``G[:, :, x_k, :]`` of every unknown, flattened to ``q r0 r1`` values, and a
    last column of ones. The point's weights times (a window of) the table give
    every unknown's interpolated core slice and, in the last column, the sum of
    the weights; the slices are chained by one batched product. Cores of more
    than ``ROW_FIRST_MAX`` slice values are contracted with the running vector
    first instead (``(q, 1, r0) @ (q, r0, n r1)``): that product's output stays
    in the first-level cache, where the table's would not (a quarter faster on the
    wide middle cores of the 7-D rigid body); its weights are then applied by one
    gemv of the result seen as ``(q r0, w)``.

    The first two cores are merged into one table (see :meth:`_pair`) when the
    first coordinate's window (a time slab: 6-8 nodes) is narrower than the
    bond between them, or the flops are no more: one product less, which on a
    small codebook is a large share of a point; the last two likewise, reversed
    (:attr:`tail_pair`).

    The train is contracted from both ends: the head (the merged pair, or the
    first core) from the left into ``(q, 1, r)``, the tail (every later core)
    from the right into ``(q, r, 1)``. The tail's vector of the last point is
    kept with the tail coordinates' values: a time series at fixed parameters
    (the first core is the time coordinate's in the march's codebooks) then
    costs the head only. The tail reads the same bytes from either end.
    All tables lie in one buffer (:class:`_Arena`).
    """

    def __init__(self, names: list[str], cores: list[np.ndarray], order: tuple[int, ...], points: Sequence):
        self.names = names
        self.index = {u: i for i, u in enumerate(names)}
        self.order = order
        self.points = list(points)
        self.weights_of = PointWeights(self.points).of  # a point's weights on every coordinate
        head = 2 if len(cores) > 1 and self._merges(cores[0], cores[1], points[order[0]]) else 1
        # the last two cores, reversed, merge as the first two do (the tail's first product)
        ends = [c.transpose(0, 3, 2, 1) for c in (cores[-1], cores[-2])] if len(cores) - head >= 2 else []
        tail_pair = bool(ends) and self._merges(ends[0], ends[1], points[order[-1]])
        # a table holds its core and a one per node, windows of slabs at most twice the core; merged pairs
        pairs = ([(cores[0], cores[1])] if head == 2 else []) + ([tuple(ends)] if tail_pair else [])
        arena = _Arena(sum(2 * c.size + c.shape[2] for c in cores) +
                       sum(a.shape[2] * b.shape[2] * (a.shape[0] * b.shape[3] + 1) for a, b in pairs))
        self.pair = self.head = self.tail_pair = None
        if head == 2:
            self.pair = self._pair(order[0], order[1], cores[0], cores[1], points, arena)
        else:
            self.head = self._table(order[0], cores[0], points[order[0]], arena)
        tail = list(zip(order[head:], cores[head:]))[::-1]  # last first
        if tail_pair:
            self.tail_pair = self._pair(order[-1], order[-2], ends[0], ends[1], points, arena, row=True)
            tail = tail[2:]
        # the tail's other cores, last first: (coordinate index, through the table?, rows by node, windows, shape)
        self.tail = [self._table(j, core, points[j], arena, True) if core.size <= ROW_FIRST_MAX * core.shape[2]
                     else self._vector_first(j, core, points[j], arena) for j, core in tail]
        self.tail_coordinates = tuple(j for j, *_ in self.tail) + (self.tail_pair[:2] if tail_pair else ())
        # the cache key: the tail coordinates' values (a tuple, or the one value; () without a tail)
        self._tail_key = itemgetter(*self.tail_coordinates) if self.tail_coordinates else (lambda xs: ())
        self.head_coordinates = tuple(j for j in range(len(points)) if j not in self.tail_coordinates)
        self._cache = None  # (tail coordinates' values, tail vector (q, 1, r), its scale)

    @staticmethod
    def _table(j: int, core: np.ndarray, point: PointData, arena: _Arena, transposed: bool = False) -> tuple:
        """A core as a table of one row per node: the stacked slices (q r0 r1 values, or with
        ``transposed`` the slices' transposes, q r1 r0) and a one (the weights' sum)."""
        q, r0, n, r1 = core.shape
        table = arena.empty((n, q * r0 * r1 + 1))
        table[:, :-1] = core.transpose(2, 0, 3, 1).reshape(n, -1) if transposed else \
            core.transpose(2, 0, 1, 3).reshape(n, -1)
        table[:, -1] = 1.0  # the weights' sum
        return j, True, table, point.windows(table), (q, r1, r0) if transposed else (q, r0, r1)

    @staticmethod
    def _vector_first(j: int, core: np.ndarray, point: PointData, arena: _Arena) -> tuple:
        """A tail core contracted with the running row vector (q, 1, r1) before the weights: per
        window, the core as (q, r1, r0 w), contiguous (the product reads it row by row), the
        shape (q r0, w) of the product's result for the weights' gemv, and that of the new vector."""
        q, r0, n, r1 = core.shape
        swapped = arena.empty((q, r1, r0, n))
        swapped[...] = core.transpose(0, 3, 1, 2)
        by_node = [swapped[:, :, :, k] for k in range(n)]  # strided (q, r1, r0) views: BLAS takes them
        windows = []
        for lo, hi in point.window_bounds():
            window = swapped
            if (lo, hi) != (0, n):
                window = arena.empty((q, r1, r0, hi - lo))
                window[...] = swapped[:, :, :, lo:hi]
            windows.append((window.reshape(q, r1, r0 * (hi - lo)), (q * r0, hi - lo), (q, 1, r0)))
        return j, False, by_node, windows, (q, r1)

    @staticmethod
    def _merges(first: np.ndarray, second: np.ndarray, point: PointData) -> bool:
        """Whether two cores are cheaper merged: per point ``w n2 q r2`` multiply-adds instead of
        ``w q r1 + n2 q r1 r2`` (w: the first coordinate's window), or about as many and one product
        less (a product's call costs as much as thousands of multiply-adds)."""
        q, _, n1, r1 = first.shape
        _, _, n2, r2 = second.shape
        width = max(hi - lo for lo, hi in point.window_bounds())
        apart = width * (q * r1 + 1) + n2 * (q * r1 * r2 + 1) + q * r1 * r2
        fewer = width < r1 or width * n2 * (q * r2 + 1) <= apart
        return fewer and n2 * (q * r2 + 1) <= ROW_FIRST_MAX and n1 * n2 * (q * r2 + 1) <= PAIR_MAX

    @staticmethod
    def _pair(j1: int, j2: int, first: np.ndarray, second: np.ndarray, points: Sequence, arena: _Arena,
              row: bool = False) -> tuple:
        """The first two cores as one table: row ``k1`` holds, for every node ``k2`` of the second
        coordinate, the stacked ``G1[:, 0, k1, :] G2[:, :, k2, :]`` (``q r2`` values) and a one.
        The last two, reversed, give the tail's first vector: then shaped as a ``row`` (q, 1, r2)."""
        q, _, n1, _ = first.shape
        _, _, n2, r2 = second.shape
        table = arena.empty((n1, n2, q * r2 + 1))
        table[:, :, :-1] = np.einsum("iar,irbs->abis", first[:, 0], second).reshape(n1, n2, q * r2)
        table[:, :, -1] = 1.0  # the first weights' sum, then (second gemv) the product of both sums
        table = table.reshape(n1, -1)
        return (j1, j2, table, points[j1].windows(table), points[j2].window_bounds(), (n2, q * r2 + 1),
                (q, 1, r2) if row else (q, r2, 1))

    @staticmethod
    def _at_pair(pair: tuple, weights: list) -> tuple[np.ndarray, float]:
        """The vector after two merged cores (see :meth:`_pair`), and its scale."""
        j1, j2, table, windows, bounds, middle, shape = pair
        k, c = weights[j1]
        row = (table[k] if c is None else _dot(c, windows[k])).reshape(middle)  # (n2, q r2 + 1)
        k, c = weights[j2]
        if c is None:
            row = row[k]
        else:
            lo, hi = bounds[k]
            row = _dot(c, row[lo:hi])
        return row[:-1].reshape(shape), row[-1]

    def at_point(self, xs: list[float]) -> list[float]:
        """Values of the stacked unknowns at one point (``xs``: a value per coordinate, codebook order).

        Raises QueryError for the first coordinate (codebook order) outside its domain.
        """
        points = self.points
        key = self._tail_key(xs)
        cache = self._cache
        if cache is not None and cache[0] == key:  # the tail's values were checked when cached
            weights = [None] * len(points)
            for j in self.head_coordinates:
                p = points[j]
                weights[j] = p.weights(p.clipped(xs[j]))
            tail, tail_scale = cache[1], cache[2]
        else:
            weights = self.weights_of(xs)
            tail, tail_scale = self._at_tail(weights)
            self._cache = (key, tail, tail_scale)  # one assignment: other threads see old or new
        if self.pair is not None:
            v, scale = self._at_pair(self.pair, weights)
        else:
            j, _, rows, windows, shape = self.head
            k, c = weights[j]
            row = rows[k] if c is None else _dot(c, windows[k])  # the core slice at x, and sum(c)
            v, scale = row[:-1].reshape(shape[0], shape[2], 1), row[-1]  # (q, 1, r1) as a column
        if tail is not None:
            v = _matmul(tail, v)  # (q, 1, r) @ (q, r, 1)
        scale = float(scale * tail_scale)
        return [value / scale for value in v.reshape(-1).tolist()]

    def _at_tail(self, weights: list) -> tuple[np.ndarray | None, float]:
        """The tail contracted from the right at the point's ``weights``: a row (q, 1, r) and its scale (None: no tail).

        The running vector is a row (q, 1, r1) times the transposed slices (q, r1, r0): every
        product then reads its matrix row by row, as the head's do (a little faster than as
        (q, r0 w, r1) times a column).
        """
        v, scale = (None, 1.0) if self.tail_pair is None else self._at_pair(self.tail_pair, weights)
        for j, through_table, rows, windows, shape in self.tail:
            k, c = weights[j]
            if through_table:
                row = rows[k] if c is None else _dot(c, windows[k])  # the core slice at x, and sum(c)
                scale *= row[-1]
                g = row[:-1].reshape(shape)  # (q, r1, r0); the last core's (r1 = 1) is the row itself
                v = g if v is None else _matmul(v, g)  # (q, 1, r0)
                continue
            if v is None:
                v = np.ones((shape[0], 1, 1))  # (q, 1, r_d = 1)
            if c is None:
                v = _matmul(v, rows[k])
            else:  # (q, 1, r0 w) as (q r0, w) times the weights: (q, 1, r0)
                window, flat, out = windows[k]
                scale *= _add_reduce(c)
                v = _dot(_matmul(v, window).reshape(flat), c).reshape(out)
        return v, scale

    @classmethod
    def build(cls, fields: Mapping, points: Sequence[PointData]) -> "TTStack | None":
        """The stack of the tensor-train unknowns that share the first one's core order (None: no train).

        Parameters
        ----------
        fields : mapping
            Unknown name -> field (only the tensor trains are stacked).
        points : sequence of PointData
            Per coordinate (codebook order).
        """
        tts = {u: f for u, f in fields.items() if isinstance(f, TT)}
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
