"""Chebyshev-Lobatto points, Clenshaw-Curtis weights and barycentric interpolation on [-1, 1] and
on a domain: the numerics under :mod:`pgdcli.discretization.basis`'s Chebyshev bases and the
codebook's evaluation. numpy only (the query path).
"""

from __future__ import annotations

import numpy as np

__all__ = ["chebyshev_unit_nodes", "clenshaw_curtis_unit_weights", "map_to_domain", "barycentric_columns",
           "barycentric_rows"]


def chebyshev_unit_nodes(n: int) -> np.ndarray:
    """The n Chebyshev-Lobatto points on [-1, 1], ascending, shape (n,)."""
    # sin form of -cos(pi j / (n - 1)): symmetric to the last bit, exact 0 at the centre
    m = n - 1
    return np.sin(np.pi * (2.0 * np.arange(n) - m) / (2.0 * m))


def clenshaw_curtis_unit_weights(n: int) -> np.ndarray:
    """Clenshaw-Curtis weights on [-1, 1] for the n Chebyshev-Lobatto points (Trefethen's clencurt)."""
    m = n - 1
    if m == 1:
        return np.array([1.0, 1.0])
    theta = np.pi * np.arange(n) / m
    w = np.zeros(n)
    inner = theta[1:-1]
    v = np.ones(m - 1)
    if m % 2 == 0:
        w[0] = w[-1] = 1.0 / (m * m - 1)
        for k in range(1, m // 2):
            v -= 2.0 * np.cos(2 * k * inner) / (4 * k * k - 1)
        v -= np.cos(m * inner) / (m * m - 1)
    else:
        w[0] = w[-1] = 1.0 / (m * m)
        for k in range(1, (m - 1) // 2 + 1):
            v -= 2.0 * np.cos(2 * k * inner) / (4 * k * k - 1)
    w[1:-1] = 2.0 * v / m
    return w


def map_to_domain(unit: np.ndarray, domain: tuple[float, float]) -> np.ndarray:
    """Points of [-1, 1] mapped affinely onto ``domain``, its ends exactly."""
    low, high = domain
    x = low + (high - low) * (unit + 1.0) / 2.0
    x[0], x[-1] = low, high  # exact ends: queries at the domain bounds hit nodes
    return x


def barycentric_columns(x: np.ndarray, nodes: np.ndarray, bary: np.ndarray, out: np.ndarray,
                        work: np.ndarray) -> np.ndarray:
    """Barycentric cardinal functions on ``nodes`` at the points ``x``, points last.

    Parameters
    ----------
    x : ndarray, shape (p,)
    nodes, bary : ndarray, shape (m,)
        The nodes and their barycentric weights.
    out, work : ndarray, shape (m, p)
        Receives the values (returned) / scratch; views of any strides.

    Returns
    -------
    ndarray, shape (m, p): ``out``
        Column ``i`` holds the cardinal functions at ``x[i]``: the textbook arithmetic,
        ``c = bary / (x - nodes)``, ``c / c.sum()``, with a point on node ``k`` given the unit
        vector ``e_k``. Such a point is found through its sum, which is not finite
        (``bary / 0 = inf``), so no (m, p) comparison is made unless needed.
    """
    diff = np.subtract(x, nodes[:, None], out=work)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.divide(bary[:, None], diff, out=out)
        total = np.add.reduce(c, axis=0)
    odd = np.flatnonzero(~np.isfinite(total))
    if odd.size:
        exact = diff[:, odd] == 0.0
        hit = exact.any(axis=0)
        c[:, odd[hit]] = exact[:, hit]
        total[odd[hit]] = 1.0  # the sum of a unit vector
    return np.divide(c, total, out=c)


def barycentric_rows(x: np.ndarray, nodes: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Barycentric cardinal rows of the points ``x`` (shape (p,)) on ``nodes`` (shape (m,), or
    (p, m): each point's own nodes), shape (p, m); a point on a node gets the unit row."""
    diff = x[:, None] - nodes
    exact = diff == 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        c = bary / diff
    hit = exact.any(axis=1)
    if hit.any():
        c[hit] = exact[hit]
    c /= c.sum(axis=1, keepdims=True)
    return c
