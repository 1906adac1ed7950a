"""One-dimensional discretizations: nodes, quadrature, interpolation, time operators.

Every coordinate of a problem is discretized on its own by a nodal basis: a
function of that coordinate is stored by its values at ``nodes`` and evaluated
elsewhere with the basis's own interpolant. Two bases are provided:

``chebyshev`` (default)
    Chebyshev-Gauss-Lobatto nodes, Clenshaw-Curtis quadrature, the spectral
    differentiation matrix and barycentric Lagrange interpolation. Smooth
    solutions converge exponentially in the number of nodes.
``linear``
    Uniform nodes with piecewise-linear (hat) functions, trapezoidal
    quadrature and, in time, the continuous Galerkin cG(1) scheme (the
    paper's linear finite elements with element-wise tests): second order.

The time coordinate carries an initial-value problem ``u(t0) = u0``. Its
operators are returned on the full node set, tested by ``n - 1`` equations
(one per free node, or per element), so that the solver can drop the first
column (the lifted unknown vanishes at ``t0``) and apply the full matrices to
the lift.

This module imports numpy only: it is on the query path.
"""

from __future__ import annotations

from functools import cached_property
from dataclasses import dataclass, field

import numpy as np

from .chebyshev import (barycentric_columns, barycentric_rows, chebyshev_unit_nodes, clenshaw_curtis_unit_weights,
                        map_to_domain)

__all__ = [
    "Basis1D",
    "ChebyshevBasis",
    "PiecewiseChebyshevBasis",
    "LinearBasis",
    "SlabRows",
    "make_basis",
    "chebyshev_unit_nodes",
    "barycentric_columns",
    "barycentric_rows",
    "KINDS",
]

KINDS = ("chebyshev", "linear")
#: A piecewise basis of at most this many slabs' nodes gives a series dense interpolation rows.
DENSE_SLABS = 32


@dataclass(frozen=True, eq=False)
class Basis1D:
    """A nodal basis on ``domain``.

    Attributes
    ----------
    domain : tuple of float
        ``(low, high)`` with ``low < high``.
    nodes : ndarray, shape (n,)
        Increasing; ``nodes[0] == low`` and ``nodes[-1] == high`` exactly.
    weights : ndarray, shape (n,)
        Quadrature weights: ``weights @ f(nodes)`` approximates the integral
        of ``f`` over the domain.
    """

    domain: tuple[float, float]
    size: int
    kind: str = field(init=False, default="")
    nodes: np.ndarray = field(init=False, repr=False)
    weights: np.ndarray = field(init=False, repr=False)

    def interpolation_matrix(self, x) -> np.ndarray:
        """Values of the ``n`` nodal basis functions at points ``x``.

        Parameters
        ----------
        x : array_like, shape (p,)
            Evaluation points (no domain check here).

        Returns
        -------
        ndarray, shape (p, n)
            Row ``i`` holds the cardinal functions at ``x[i]``; at a node the
            row is exactly the corresponding unit vector.
        """
        raise NotImplementedError

    def interpolation_rows(self, x: np.ndarray, out: np.ndarray, work: np.ndarray | None = None) -> np.ndarray:
        """:meth:`interpolation_matrix` of ``x`` written into caller-owned buffers.

        Parameters
        ----------
        x : ndarray, shape (p,)
            Evaluation points, float (no domain check here).
        out : ndarray, shape (p, n)
            Receives the rows; returned.
        work : ndarray, shape (p, n), optional
            Scratch (the Chebyshev basis's differences); allocated when not given.

        Returns
        -------
        ndarray, shape (p, n): ``out``
        """
        raise NotImplementedError

    def interpolate(self, values, x) -> np.ndarray:
        """Interpolate nodal ``values`` (shape (n, ...)) at ``x`` (shape (p,)): shape (p, ...)."""
        values = np.asarray(values, dtype=float)
        matrix = self.interpolation_matrix(np.atleast_1d(np.asarray(x, dtype=float)))
        return np.tensordot(matrix, values, axes=(1, 0))

    def series_rows(self, x) -> "np.ndarray | SlabRows":
        """The rows of :meth:`interpolation_matrix` at ``x`` (shape (p,)) in the form cheapest to apply to
        nodal values of every point of a series: the dense (p, n) matrix here, :class:`SlabRows` where each
        row has a few nonzeros among many nodes."""
        return self.interpolation_matrix(x)

    # -- time discretization of  c(t) u'(t)  and  c(t) u(t)  (n - 1 test equations) --
    def time_stiffness(self, c) -> np.ndarray:
        """Discrete ``c(t) u'(t)``, shape (n - 1, n), from ``c`` at the nodes (shape (n,))."""
        raise NotImplementedError

    def time_mass(self, c) -> np.ndarray:
        """Discrete ``c(t) u(t)``, shape (n - 1, n), from ``c`` at the nodes (shape (n,))."""
        raise NotImplementedError

    def time_load(self, f) -> np.ndarray:
        """Discrete source ``f(t)`` tested like the equations, shape (n - 1,)."""
        raise NotImplementedError

    def time_weights(self) -> np.ndarray:
        """Weights, shape (n - 1,), of the discrete L2 norm on the free nodes 1..n-1."""
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class ChebyshevBasis(Basis1D):
    """Chebyshev-Gauss-Lobatto nodal spectral basis."""

    bary: np.ndarray = field(init=False, repr=False)
    derivative: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        n = int(self.size)
        if n < 2:
            raise ValueError(f"a Chebyshev basis needs at least 2 nodes, got {n}")
        low, high = map(float, self.domain)
        object.__setattr__(self, "kind", "chebyshev")
        object.__setattr__(self, "nodes", map_to_domain(chebyshev_unit_nodes(n), (low, high)))
        object.__setattr__(self, "weights", clenshaw_curtis_unit_weights(n) * (high - low) / 2.0)
        bary = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
        bary[0] *= 0.5
        bary[-1] *= 0.5
        object.__setattr__(self, "bary", bary)
        object.__setattr__(self, "derivative", self._derivative_matrix())

    def _derivative_matrix(self) -> np.ndarray:
        x, w = self.nodes, self.bary
        diff = x[:, None] - x[None, :]
        np.fill_diagonal(diff, 1.0)
        d = (w[None, :] / w[:, None]) / diff
        np.fill_diagonal(d, 0.0)
        # negative-sum trick: rows of D annihilate constants to rounding error
        np.fill_diagonal(d, -d.sum(axis=1))
        return d

    def interpolation_matrix(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float).reshape(-1)
        n = self.nodes.size
        return self.interpolation_rows(x, np.empty((x.size, n)), np.empty((x.size, n)))

    def interpolation_rows(self, x, out, work=None) -> np.ndarray:
        """:meth:`interpolation_matrix` of ``x`` (shape (p,)) written into ``out`` (shape (p, n)).

        ``work`` is scratch of the same shape (allocated if None). The arithmetic of
        :func:`barycentric_columns` on the transposed views (the same values bit for bit as
        row by row: numpy sums along memory either way).
        """
        work = np.empty_like(out) if work is None else work
        barycentric_columns(x, self.nodes, self.bary, out.T, work.T)
        return out

    def time_stiffness(self, c) -> np.ndarray:
        c = np.asarray(c, dtype=float)
        return c[1:, None] * self.derivative[1:, :]

    def time_mass(self, c) -> np.ndarray:
        c = np.asarray(c, dtype=float)
        n = self.nodes.size
        m = np.zeros((n - 1, n))
        m[np.arange(n - 1), np.arange(1, n)] = c[1:]
        return m

    def time_load(self, f) -> np.ndarray:
        return np.asarray(f, dtype=float)[1:].copy()

    def time_weights(self) -> np.ndarray:
        return self.weights[1:].copy()


@dataclass(frozen=True, eq=False)
class LinearBasis(Basis1D):
    """Piecewise-linear (hat function) basis on uniform nodes."""

    def __post_init__(self):
        n = int(self.size)
        if n < 2:
            raise ValueError(f"a linear basis needs at least 2 nodes, got {n}")
        low, high = map(float, self.domain)
        nodes = np.linspace(low, high, n)
        nodes[0], nodes[-1] = low, high
        h = np.diff(nodes)
        w = np.zeros(n)
        w[:-1] += h / 2.0
        w[1:] += h / 2.0
        object.__setattr__(self, "kind", "linear")
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "weights", w)

    def interpolation_matrix(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float).reshape(-1)
        return self.interpolation_rows(x, np.empty((x.size, self.nodes.size)), None)

    def interpolation_rows(self, x, out, work=None) -> np.ndarray:
        """:meth:`interpolation_matrix` of ``x`` (shape (p,)) written into ``out`` (shape (p, n)); no scratch."""
        nodes = self.nodes
        n = nodes.size
        left = np.clip(np.searchsorted(nodes, x, side="right") - 1, 0, n - 2)
        theta = (x - nodes[left]) / (nodes[left + 1] - nodes[left])
        out.fill(0.0)
        rows = np.arange(x.size)
        out[rows, left] = 1.0 - theta
        out[rows, left + 1] = theta
        return out

    # cG(1): continuous piecewise-linear trial functions, one piecewise-constant
    # test function per element. For u' = f this is the trapezoidal rule
    # (Crank-Nicolson), A-stable and second order, unlike the plain Galerkin
    # hat-function test whose d/dt block is not coercive.
    def _element_sum(self, values) -> np.ndarray:
        n = self.nodes.size
        m = np.zeros((n - 1, n))
        e = np.arange(n - 1)
        m[e, e] = values[:-1]
        m[e, e + 1] = values[1:]
        return m

    def time_stiffness(self, c) -> np.ndarray:
        c = np.asarray(c, dtype=float)
        mean = 0.5 * (c[:-1] + c[1:])
        n = self.nodes.size
        m = np.zeros((n - 1, n))
        e = np.arange(n - 1)
        m[e, e] = -mean
        m[e, e + 1] = mean
        return m

    def time_mass(self, c) -> np.ndarray:
        c = np.asarray(c, dtype=float)
        h = np.diff(self.nodes)
        return 0.5 * h[:, None] * self._element_sum(c)

    def time_load(self, f) -> np.ndarray:
        f = np.asarray(f, dtype=float)
        h = np.diff(self.nodes)
        return 0.5 * h * (f[:-1] + f[1:])

    def time_weights(self) -> np.ndarray:
        return self.weights[1:].copy()


@dataclass(frozen=True, eq=False)
class PiecewiseChebyshevBasis(Basis1D):
    """Chebyshev-Lobatto nodes on each slab ``[b_s, b_{s+1}]`` of ``breakpoints``; slabs share ends.

    ``size`` is the total number of nodes, ``S (m - 1) + 1`` for ``S`` slabs of
    ``m`` nodes. Functions are continuous, polynomial of degree ``m - 1`` on
    each slab (barycentric interpolation within the slab of the point; a
    breakpoint belongs to the slab on its right, where it is a node either
    way). In time, each node's equation is collocated with the derivative of
    the slab on its left (the first node: the first slab), so the composite
    system marches slab by slab like the single-slab one.
    """

    breakpoints: tuple = ()
    bary: np.ndarray = field(init=False, repr=False)
    slab_size: int = field(init=False, default=0)

    def __post_init__(self):
        bp = np.asarray(self.breakpoints, dtype=float)
        slabs = bp.size - 1
        n = int(self.size)
        if slabs < 1 or np.any(np.diff(bp) <= 0):
            raise ValueError(f"breakpoints must increase, got {self.breakpoints}")
        if (n - 1) % slabs or (n - 1) // slabs < 1:
            raise ValueError(f"{n} nodes do not make {slabs} slabs of equal node counts")
        m = (n - 1) // slabs + 1
        bp[0], bp[-1] = float(self.domain[0]), float(self.domain[1])
        unit = chebyshev_unit_nodes(m)
        nodes, weights = np.empty(n), np.zeros(n)
        local_w = clenshaw_curtis_unit_weights(m)
        for s in range(slabs):
            a, b = bp[s], bp[s + 1]
            idx = slice(s * (m - 1), s * (m - 1) + m)
            nodes[idx] = map_to_domain(unit.copy(), (a, b))
            weights[idx] += local_w * (b - a) / 2.0
        bary = np.where(np.arange(m) % 2 == 0, 1.0, -1.0)
        bary[0] *= 0.5
        bary[-1] *= 0.5
        object.__setattr__(self, "kind", "chebyshev")
        object.__setattr__(self, "breakpoints", tuple(float(v) for v in bp))
        object.__setattr__(self, "slab_size", m)
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "bary", bary)

    @cached_property
    def derivative(self) -> np.ndarray:
        """Differentiation matrix at the nodes, shape (n, n): each slab's, a shared node taking its
        left slab's row. Built on first use: a march's time basis (one slab per step, up to
        ``max_steps`` of them) is only interpolated, and n x n values would not fit in memory."""
        n, m, bp = self.nodes.size, self.slab_size, self.breakpoints
        local_d = ChebyshevBasis((-1.0, 1.0), m).derivative
        derivative = np.zeros((n, n))
        for s in range(len(bp) - 1):
            first = 0 if s == 0 else 1
            block = local_d[first:] * 2.0 / (bp[s + 1] - bp[s])
            derivative[s * (m - 1) + first: s * (m - 1) + m, s * (m - 1): s * (m - 1) + m] = block
        return derivative

    def slab_of(self, x: np.ndarray) -> np.ndarray:
        """Slab index of each point (a breakpoint goes to the slab on its right, the end to the last)."""
        bp = np.asarray(self.breakpoints)
        return np.clip(np.searchsorted(bp, x, side="right") - 1, 0, bp.size - 2)

    def interpolation_matrix(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float).reshape(-1)
        return self.interpolation_rows(x, np.empty((x.size, self.nodes.size)), None)

    def interpolation_rows(self, x, out, work=None) -> np.ndarray:
        rows = self._slab_rows(x)
        out.fill(0.0)
        out[np.arange(rows.index.shape[0])[:, None], rows.index] = rows.weights
        return out

    def interpolate(self, values, x) -> np.ndarray:
        """Interpolate nodal ``values`` (shape (n, ...)) at ``x`` (shape (p,)): shape (p, ...).

        Each point's slab only: a march's time basis has a slab per step (~1e4-1e5 nodes), where
        the (p, n) matrix of :meth:`interpolation_matrix` would take gigabytes.
        """
        values = np.asarray(values, dtype=float)
        rows = self._slab_rows(x)
        return np.einsum("pm,pm...->p...", rows.weights, values[rows.index])

    def series_rows(self, x) -> "np.ndarray | SlabRows":
        """Each point's row on its slab's nodes only (:class:`SlabRows`) where the slabs are many: a series of
        a march's ~1e4 time nodes at as many times is gigabytes as a dense (p, n) matrix, and most of its
        product zeros. With few slabs (at most :data:`DENSE_SLABS` slabs' nodes), the dense matrix: one matrix
        product beats a gather per node of a slab (3.4x on 177 nodes in 22 slabs, 2e4 points x 2e3 times)."""
        if self.nodes.size <= DENSE_SLABS * self.slab_size:
            return self.interpolation_matrix(x)
        return self._slab_rows(x)

    def _slab_rows(self, x) -> "SlabRows":
        """Each point's barycentric weights on its slab's nodes (global indices of the slab's nodes)."""
        x = np.atleast_1d(np.asarray(x, dtype=float)).reshape(-1)
        idx = (self.slab_of(x) * (self.slab_size - 1))[:, None] + np.arange(self.slab_size)
        return SlabRows(idx, barycentric_rows(x, self.nodes[idx], self.bary), self.nodes.size)

    time_stiffness = ChebyshevBasis.time_stiffness
    time_mass = ChebyshevBasis.time_mass
    time_load = ChebyshevBasis.time_load
    time_weights = ChebyshevBasis.time_weights


@dataclass(frozen=True)
class SlabRows:
    """Interpolation rows with ``m`` nonzeros each, among ``size`` nodes: row ``i`` is ``weights[i]`` at the
    nodes ``index[i]``.

    Attributes
    ----------
    index : ndarray of int, shape (p, m)
    weights : ndarray, shape (p, m)
    size : int
    """

    index: np.ndarray
    weights: np.ndarray
    size: int

    @property
    def shape(self) -> tuple[int, int]:
        return (self.index.shape[0], self.size)

    def apply(self, values) -> np.ndarray:
        """The rows times nodal ``values`` (shape (size, ...)): shape (p, ...), one nonzero of every row at a
        time (no (p, m, ...) gather: a series of 1e4 parameter points at 1e4 times would take gigabytes)."""
        values = np.asarray(values, dtype=float)
        column = (-1,) + (1,) * (values.ndim - 1)
        out = self.weights[:, 0].reshape(column) * values[self.index[:, 0]]
        for k in range(1, self.index.shape[1]):
            out += self.weights[:, k].reshape(column) * values[self.index[:, k]]
        return out

    def toarray(self) -> np.ndarray:
        """The dense (p, size) matrix."""
        out = np.zeros((self.index.shape[0], self.size))
        out[np.arange(self.index.shape[0])[:, None], self.index] = self.weights
        return out


def make_basis(kind: str, domain, size: int, breakpoints=None) -> Basis1D:
    """Build the basis named ``kind`` (one of :data:`KINDS`) with ``size`` nodes on ``domain``.

    ``breakpoints`` (Chebyshev only): slab boundaries, ``domain`` ends included;
    ``size`` is then the total node count, ``slabs * (nodes per slab - 1) + 1``.
    """
    domain = (float(domain[0]), float(domain[1]))
    if kind == "chebyshev" and breakpoints is not None and len(breakpoints) > 2:
        return PiecewiseChebyshevBasis(domain, int(size), tuple(breakpoints))
    if kind == "chebyshev":
        return ChebyshevBasis(domain, int(size))
    if kind == "linear":
        return LinearBasis(domain, int(size))
    raise ValueError(f"unknown discretization {kind!r}; expected one of {', '.join(KINDS)}")
