"""Series: every point of a set of parameter points at every value of one coordinate (a time series).

The values of a codebook at the ``S x T`` points ``(p_s, t_k)`` -- ``S`` points in all
coordinates but one (the parameters of a check sample) and ``T`` values of the remaining one
(the times) -- without evaluating ``S T`` points through every core. A tensor train is
contracted from both of its ends toward the series coordinate's core once per parameter point,
into a left row ``L`` (S, r0) and a right column ``R`` (S, r1); the series core ``G`` (r0, n, r1)
then gives each point's nodal values ``Z[s, :] = L[s] G[:, :, :] R[s]`` (S, n), and one matrix
product with the cardinal rows ``W`` (T, n) of the series values gives all ``S x T`` values. A
CP field: the product over the other coordinates of the interpolated modes times the weights
(S, rank), times the interpolated modes of the series coordinate (T, rank) transposed.

Per point of the series that is ``n`` multiply-adds (and the cores once per parameter point),
where :meth:`~pgdcli.codebook.Codebook.evaluate` on the flattened points contracts every core
per point. The values are those of :meth:`~pgdcli.codebook.Codebook.evaluate` at the same
points to rounding (the same sums in another order): tests/codebook/test_series.py.
numpy only (the query path).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .fields import TT
from .threads import batch_blas

__all__ = ["evaluate_series", "series_tt", "series_cp"]


def evaluate_series(fields, mats: list, series: int, rows, selected: Sequence[str]) -> dict:
    """The ``selected`` unknowns of ``fields`` at parameter points times series values, each (S, T),
    under the batches' BLAS policy (:func:`~pgdcli.codebook.threads.batch_blas`: threaded BLAS
    makes these small products many times slower on a loaded machine). ``mats``, ``series`` and
    ``rows`` as in :func:`series_tt`."""
    points = next((m.shape[0] for j, m in enumerate(mats) if j != series), 1)
    with batch_blas(points * rows.shape[0]):
        return {u: series_tt(fields[u], mats, series, rows) if isinstance(fields[u], TT) else
                series_cp(fields[u].weights, fields[u].factors, mats, series, rows) for u in selected}


def series_tt(fm: TT, mats: list, series: int, rows) -> np.ndarray:
    """Tensor train at parameter points times series values: shape (S, T).

    Parameters
    ----------
    fm : TT
    mats : list
        Per coordinate (codebook order), the parameter points' cardinal rows (S, nodes_j);
        the entry of the series coordinate is not read.
    series : int
        Index of the series coordinate.
    rows : ndarray or SlabRows
        Cardinal rows of the series values, shape (T, nodes of the series coordinate): dense, or a march's
        time rows (:meth:`~pgdcli.discretization.basis.Basis1D.series_rows`).
    """
    cores, order = fm.cores, list(fm.mode_order)
    k = order.index(series)
    points = next((m.shape[0] for j, m in enumerate(mats) if j != series), 1)
    left = np.ones((points, 1))  # (S, r): the cores before the series core, contracted from the left
    for i, (core, j) in enumerate(zip(cores[:k], order[:k])):
        r0, n, r1 = core.shape
        if i == 0:
            left = mats[j] @ core[0]
            continue
        partial = (left @ core.reshape(r0, n * r1)).reshape(points, n, r1)  # (S, n, r1)
        left = np.matmul(mats[j][:, None, :], partial)[:, 0, :]  # each point's row times its block
    right = np.ones((points, 1))  # (S, r): the cores after it, from the right
    for i, (core, j) in enumerate(zip(cores[:k:-1], order[:k:-1])):
        r0, n, r1 = core.shape
        if i == 0:
            right = mats[j] @ core[:, :, 0].T
            continue
        partial = (right @ core.transpose(2, 0, 1).reshape(r1, r0 * n)).reshape(points, r0, n)
        right = np.matmul(partial, mats[j][:, :, None])[:, :, 0]
    r0, n, r1 = cores[k].shape
    # each point's values at the series nodes, (S, n): through the smaller of the two bonds
    if r1 <= r0:
        partial = (left @ cores[k].reshape(r0, n * r1)).reshape(points, n, r1)
        nodal = np.matmul(partial, right[:, :, None])[:, :, 0]
    else:
        partial = (right @ cores[k].transpose(2, 0, 1).reshape(r1, r0 * n)).reshape(points, r0, n)
        nodal = np.matmul(left[:, None, :], partial)[:, 0, :]
    return nodal @ rows.T if isinstance(rows, np.ndarray) else rows.apply(nodal.T).T


def series_cp(weights: np.ndarray, modes: Sequence[np.ndarray], mats: list, series: int,
              rows) -> np.ndarray:
    """CP field ``sum_r weights_r prod_j modes_j[:, r]`` at parameter points times series values: (S, T).

    ``mats``, ``series`` and ``rows`` as in :func:`series_tt`.
    """
    points = next((m.shape[0] for j, m in enumerate(mats) if j != series), 1)
    product = np.broadcast_to(weights, (points, weights.size)).copy()
    for j, (m, v) in enumerate(zip(mats, modes)):
        if j != series:
            product *= m @ v  # (S, rank)
    return product @ _at_series(rows, modes[series]).T


def _at_series(rows, values: np.ndarray) -> np.ndarray:
    """``rows`` (T, n) times ``values`` (n, k): a dense matrix's product, or the few nonzeros of each row of a
    :class:`~pgdcli.discretization.basis.SlabRows` (a march's time basis)."""
    return rows @ values if isinstance(rows, np.ndarray) else rows.apply(values)
