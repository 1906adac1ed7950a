"""One point's interpolation weights, coordinate by coordinate or a few coordinates at once.

The one-point path needs, per coordinate, the window of nodes a value falls in and the
barycentric weights on it: :class:`PointData` holds one coordinate's constants (and gives the
cardinal rows of :class:`pgdcli.codebook.evaluate.Evaluator`'s CP path); :class:`PointWeights`
gives a point's weights on every coordinate for :class:`pgdcli.codebook.point.TTStack`, those of
coordinates sharing a plain Chebyshev basis of one node count from one subtraction and one
division (the many same-size coordinates of a high-dimensional codebook pay one numpy call
instead of one each: ``benchmarks/query_speed_tt.py``). numpy only (the query path).
"""

from __future__ import annotations

from bisect import bisect_right
from operator import itemgetter
from typing import Sequence

import numpy as np

from ..discretization.coordinates import CoordinateInfo
from ..errors import QueryError
from .domain import domain_slack

__all__ = ["PointData", "PointWeights", "outside_error"]

_add_reduce, _array = np.add.reduce, np.array


class PointData:
    """Constants of one coordinate for the one-point path of :meth:`Codebook.evaluate`."""

    __slots__ = ("name", "domain", "low", "high", "lower", "upper", "chebyshev", "nodes", "node_list",
                 "node_index", "bary", "modes", "basis", "piecewise", "breaks", "slab", "slab_nodes",
                 "bounds")

    def __init__(self, c: CoordinateInfo, basis, modes: np.ndarray):
        low, high = c.domain
        slack = domain_slack(low, high)
        self.name, self.domain = c.name, c.domain
        self.low, self.high = float(low), float(high)
        self.lower, self.upper = low - slack, high + slack
        self.chebyshev = basis.kind == "chebyshev"
        self.nodes = basis.nodes
        self.node_list = basis.nodes.tolist()
        self.node_index = {v: k for k, v in enumerate(self.node_list)}
        self.bary = getattr(basis, "bary", None)
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
            raise outside_error(self, x)
        x = x if x > self.low else self.low
        return x if x < self.high else self.high

    def row(self, x: float) -> np.ndarray:
        """The cardinal row (a unit row at a node) of the clipped value ``x``, shape (nodes,)."""
        k, c = self.weights(x)
        if c is None:
            row = np.zeros(self.nodes.size)  # not rows of an identity: a march's time basis has ~1e5 nodes
            row[k] = 1.0
            return row
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


class PointWeights:
    """:meth:`PointData.weights` of every coordinate of one point, in codebook order.

    Plain Chebyshev coordinates of equal node counts (two or more) form a group: their
    weights ``bary / (x - nodes)`` are the columns of one ``(n, g)`` array, the same values
    bit for bit, from one subtraction and one division instead of two per coordinate (on
    ``(n, g)``, not ``(g, n)``: numpy broadcasts a row of values across it as fast as a plain
    elementwise operation, and a column of values three times slower). A value on a node of the
    group (or equal to any node of it) takes the coordinates' own :meth:`PointData.weights`, where
    a node gives its unit row. Thread-safe: nothing is kept between calls.
    """

    def __init__(self, points: Sequence[PointData]):
        self.points = list(points)
        by_count: dict[int, list[int]] = {}
        for j, p in enumerate(self.points):
            if p.chebyshev and not p.piecewise:
                by_count.setdefault(p.nodes.size, []).append(j)
        # (members, their values from a point's list, every node value of theirs, nodes (n, g), bary (n, g))
        self.groups = [(members, itemgetter(*members), frozenset(v for j in members for v in self.points[j].node_list),
                        np.stack([self.points[j].nodes for j in members], axis=1),
                        np.stack([self.points[j].bary for j in members], axis=1))
                       for members in by_count.values() if len(members) > 1]
        grouped = {j for members, *_ in self.groups for j in members}
        self.alone = [j for j in range(len(self.points)) if j not in grouped]
        #: ``of(xs)``: the weights (see :meth:`__call__`), the plain loop when nothing is grouped
        self.of = self._grouped if self.groups else self._each

    def __call__(self, xs: Sequence[float]) -> list[tuple[int, np.ndarray | None]]:
        """Weights ``(k, c)`` per coordinate (see :meth:`PointData.weights`) of the values ``xs``.

        Raises QueryError for the first coordinate (codebook order) outside its domain.
        """
        return self.of(xs)

    def _each(self, xs: Sequence[float]) -> list:
        return [p.weights(p.clipped(x)) for x, p in zip(xs, self.points)]

    def _grouped(self, xs: Sequence[float]) -> list:
        points = self.points
        xs = [p.clipped(x) for x, p in zip(xs, points)]
        out: list = [None] * len(points)
        for j in self.alone:
            out[j] = points[j].weights(xs[j])
        for members, values_of, node_values, nodes, bary in self.groups:
            values = values_of(xs)
            if not node_values.isdisjoint(values):
                for j in members:  # a node: its unit row, not a division by zero
                    out[j] = points[j].weights(xs[j])
                continue
            for j, column in zip(members, (bary / (_array(values) - nodes)).T):
                out[j] = (0, column)
        return out


def outside_error(p: PointData, x: float) -> QueryError:
    """The out-of-domain error of one point (the batch path's message)."""
    low, high = p.domain
    return QueryError(f"coordinate {p.name!r}: value {x!r} is outside the domain [{low:g}, {high:g}]")

