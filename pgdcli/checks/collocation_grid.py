"""Strong-form Chebyshev-Gauss-Lobatto collocation from scratch: nodes, barycentric weights,
differentiation matrices, barycentric interpolation and the tensor grid of the space coordinates.

Part of the independent reference (:mod:`.collocation` builds a problem's operator on this grid):
shares nothing with the PGD solver's weak-form discretization (pgdcli.discretization).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

__all__ = ["chebyshev_points", "chebyshev_weights", "chebyshev_differentiation", "barycentric_matrix", "SpaceGrid"]


def chebyshev_points(n: int, domain: tuple[float, float] = (-1.0, 1.0)) -> np.ndarray:
    """The ``n`` Chebyshev-Gauss-Lobatto points of ``domain``, ascending, ends exact.

    ``x_j = low + (1 + s_j) (high - low) / 2`` with ``s_j = -cos(pi j / (n - 1))``
    (computed as a sine, so that the points are symmetric to rounding).
    """
    if n < 2:
        raise ValueError(f"need at least 2 Chebyshev points, got {n}")
    low, high = map(float, domain)
    j = np.arange(n)
    s = np.sin(np.pi * (2 * j - (n - 1)) / (2 * (n - 1)))
    x = low + (1.0 + s) * (0.5 * (high - low))
    x[0], x[-1] = low, high
    return x


def chebyshev_weights(n: int) -> np.ndarray:
    """Barycentric weights of the Chebyshev-Gauss-Lobatto points (ascending order)."""
    w = (-1.0) ** np.arange(n)
    w[0] *= 0.5
    w[-1] *= 0.5
    return w


def chebyshev_differentiation(n: int, domain: tuple[float, float] = (-1.0, 1.0)) -> np.ndarray:
    """First-derivative collocation matrix ``D`` on :func:`chebyshev_points` (``(D u)_i = u'(x_i)``
    for polynomials of degree < n).

    Off-diagonal ``D_ij = (w_j / w_i) / (x_i - x_j)`` with the barycentric weights, the node
    differences from trigonometric identities (no cancellation near the ends), and the diagonal
    from the negative sum of its row (exact derivative of constants).
    """
    low, high = map(float, domain)
    theta = np.pi * np.arange(n) / (n - 1)  # x = low + (1 - cos theta) (high - low) / 2
    ti, tj = theta[:, None], theta[None, :]
    diff = (high - low) * np.sin(0.5 * (ti + tj)) * np.sin(0.5 * (ti - tj))  # x_i - x_j
    w = chebyshev_weights(n)
    with np.errstate(divide="ignore"):
        D = (w[None, :] / w[:, None]) / diff
    np.fill_diagonal(D, 0.0)
    np.fill_diagonal(D, -D.sum(axis=1))
    return D


def barycentric_matrix(nodes: np.ndarray, weights: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Interpolation matrix ``W`` (P, n): ``W @ f(nodes)`` interpolates at ``points``
    (barycentric formula of the second kind; a point on a node takes that node's value)."""
    nodes = np.asarray(nodes, dtype=float)
    points = np.atleast_1d(np.asarray(points, dtype=float))
    diff = points[:, None] - nodes[None, :]
    scale = max(1.0, float(np.max(np.abs(nodes))))
    hit = np.abs(diff) <= 1e-15 * scale
    with np.errstate(divide="ignore", invalid="ignore"):
        r = weights[None, :] / diff
        W = r / r.sum(axis=1, keepdims=True)
    rows = hit.any(axis=1)
    if rows.any():
        W[rows] = 0.0
        W[rows, np.argmax(hit[rows], axis=1)] = 1.0
    return W


class SpaceGrid:
    """Tensor-product Chebyshev-Gauss-Lobatto grid over the space coordinates (C order, spec order)."""

    def __init__(self, coordinates, nodes: Mapping[str, int]) -> None:
        import scipy.sparse as sp

        self.names = [c.name for c in coordinates]
        self.domains = {c.name: tuple(map(float, c.domain)) for c in coordinates}
        self.points = {c.name: chebyshev_points(nodes[c.name], c.domain) for c in coordinates}
        self.weights = {n: chebyshev_weights(x.size) for n, x in self.points.items()}
        self.shape = tuple(self.points[n].size for n in self.names)
        self.n = int(np.prod(self.shape))
        self.index = {n: ix.reshape(-1) for n, ix in zip(self.names, np.indices(self.shape))}
        self.values = {n: self.points[n][self.index[n]] for n in self.names}
        self._ops: dict = {}
        self._sp = sp

    def derivative(self, name: str, order: int):
        """Sparse (n, n) matrix of ``d^order/dx^order`` along one coordinate on the full grid."""
        key = (name, order)
        if key not in self._ops:
            sp = self._sp
            D = chebyshev_differentiation(self.points[name].size, self.domains[name])
            if order == 2:
                D = D @ D
            k = self.names.index(name)
            before = int(np.prod(self.shape[:k]))
            after = int(np.prod(self.shape[k + 1:]))
            self._ops[key] = sp.kron(sp.kron(sp.identity(before), sp.csr_matrix(D)), sp.identity(after),
                                     format="csr")
        return self._ops[key]
