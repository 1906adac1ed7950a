"""Derivatives of a codebook with respect to its coordinates.

Each coordinate's interpolant is differentiated exactly: a Chebyshev
interpolant ``p(x) = L(x) f`` (``L`` the barycentric cardinal row) has the
derivative ``L(x) (D f)`` with ``D`` the spectral differentiation matrix on
the nodes (``p'`` is a polynomial of lower degree, so interpolating its nodal
values reproduces it); piecewise Chebyshev slabs take the same on the slab of
the point (a breakpoint belongs to the slab on its right, as in evaluation);
linear elements have the piecewise-constant slope of the element on the right
of the point (the last element at the upper end). The derivative rows then
replace the cardinal rows of one coordinate in the same contraction as the
evaluation (CP sum or tensor train), so a gradient costs about one
evaluation per coordinate differentiated.

This module imports numpy only.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .basis import ChebyshevBasis, LinearBasis, PiecewiseChebyshevBasis

__all__ = ["derivative_matrix", "gradient_points", "gradient_grid"]


def derivative_matrix(basis, x) -> np.ndarray:
    """Derivatives of the ``n`` cardinal functions of ``basis`` at points ``x``.

    Parameters
    ----------
    basis : pgdcli.basis.Basis1D
    x : array_like, shape (p,)
        Points in the basis's domain (not checked).

    Returns
    -------
    ndarray, shape (p, n)
        ``derivative_matrix(b, x) @ f`` is the derivative at ``x`` of the interpolant of the
        nodal values ``f``.
    """
    x = np.asarray(x, dtype=float).reshape(-1)
    if isinstance(basis, PiecewiseChebyshevBasis):
        return _slab_rows(basis, x)
    if isinstance(basis, ChebyshevBasis):
        return basis.interpolation_matrix(x) @ basis.derivative
    if isinstance(basis, LinearBasis):
        nodes = basis.nodes
        n = nodes.size
        left = np.clip(np.searchsorted(nodes, x, side="right") - 1, 0, n - 2)
        slope = 1.0 / (nodes[left + 1] - nodes[left])
        out = np.zeros((x.size, n))
        rows = np.arange(x.size)
        out[rows, left] = -slope
        out[rows, left + 1] = slope
        return out
    raise TypeError(f"no derivative for a basis of kind {getattr(basis, 'kind', type(basis).__name__)!r}")


def _slab_rows(basis: PiecewiseChebyshevBasis, x: np.ndarray) -> np.ndarray:
    m = basis.slab_size
    slabs = basis.slab_of(x)
    out = np.zeros((x.size, basis.nodes.size))
    bp = basis.breakpoints
    for s in np.unique(slabs):
        local = ChebyshevBasis((bp[s], bp[s + 1]), m)
        first = s * (m - 1)
        # the slab's own nodes (as the composite basis stores them) and its differentiation matrix
        local_nodes = basis.nodes[first:first + m]
        assert np.array_equal(local.nodes, local_nodes)
        rows = slabs == s
        out[np.ix_(rows, np.arange(first, first + m))] = local.interpolation_matrix(x[rows]) @ local.derivative
    return out


def _wrt_indices(names: Sequence[str], wrt: Sequence[str]) -> list[int]:
    return [list(names).index(w) for w in wrt]


def gradient_points(fields, bases, flat, wrt: Sequence[int], selected: Sequence[str]) -> dict:
    """Derivatives at points given coordinate by coordinate (already checked).

    Parameters
    ----------
    fields : mapping
        Unknown name -> ``FieldModes`` or ``FieldTT`` (duck-typed: ``alphas``/``modes`` or
        ``cores``/``mode_order``).
    bases : sequence of Basis1D, one per coordinate
    flat : sequence of ndarray, each shape (P,)
        The points' values per coordinate.
    wrt : sequence of int
        Coordinates (indices) to differentiate with respect to.
    selected : sequence of str
        Unknowns.

    Returns
    -------
    dict
        ``out[u][k]``: ndarray (P,), the derivative of ``u`` with respect to coordinate ``wrt[k]``.
    """
    mats = [b.interpolation_matrix(x) for b, x in zip(bases, flat)]
    dmats = {j: derivative_matrix(bases[j], flat[j]) for j in wrt}
    out = {}
    for u in selected:
        fm = fields[u]
        if hasattr(fm, "cores"):
            out[u] = [_tt_points(fm, _swap(mats, j, dmats[j])) for j in wrt]
        else:
            vs = [m @ modes for m, modes in zip(mats, fm.modes)]  # (P, rank)
            out[u] = []
            for j in wrt:
                prod = dmats[j] @ fm.modes[j]
                for k, v in enumerate(vs):
                    if k != j:
                        prod = prod * v
                out[u].append(prod @ fm.alphas)
    return out


def _swap(mats: list, j: int, replacement: np.ndarray) -> list:
    out = list(mats)
    out[j] = replacement
    return out


def _tt_points(fm, mats: list[np.ndarray]) -> np.ndarray:
    """Tensor train at points whose rows per coordinate are ``mats[j]`` (P, nodes_j): shape (P,)."""
    v = None
    for core, j in zip(fm.cores, fm.mode_order):
        r0, n, r1 = core.shape
        if v is None:
            v = mats[j] @ core[0]
        else:
            kr = (v[:, :, None] * mats[j][:, None, :]).reshape(v.shape[0], r0 * n)
            v = kr @ core.reshape(r0 * n, r1)
    return v[:, 0]


def gradient_grid(fields, bases, axes, wrt: Sequence[int], selected: Sequence[str], values: bool = False) -> dict:
    """Derivatives on the cartesian grid of per-coordinate values (already checked).

    Parameters
    ----------
    fields, bases, wrt, selected
        As in :func:`gradient_points`.
    axes : sequence of ndarray, each shape (P_j,)
    values : bool
        Also return the values (key ``None`` in the per-unknown list's place: see Returns).

    Returns
    -------
    dict
        ``out[u]``: list of ndarray of shape (P_1, ..., P_d), one per ``wrt`` entry; with
        ``values`` the values of ``u`` are appended as the last entry.
    """
    mats = [b.interpolation_matrix(x) for b, x in zip(bases, axes)]
    dmats = {j: derivative_matrix(bases[j], axes[j]) for j in wrt}
    variants = [_swap(mats, j, dmats[j]) for j in wrt] + ([mats] if values else [])
    out = {}
    for u in selected:
        fm = fields[u]
        grid = _tt_grid if hasattr(fm, "cores") else _cp_grid
        out[u] = [grid(fm, m) for m in variants]
    return out


def _cp_grid(fm, mats: list[np.ndarray]) -> np.ndarray:
    vs = [m @ modes for m, modes in zip(mats, fm.modes)]  # (P_j, rank)
    letters = "abcdefghijklmnopqrstuvwxyz"[: len(vs)]
    return np.einsum(",".join(f"{l}z" for l in letters) + ",z->" + letters, *vs, fm.alphas, optimize=True)


def _tt_grid(fm, mats: list[np.ndarray]) -> np.ndarray:
    """Tensor train on a grid, contracted from both ends toward the core with the longest axis.

    A grid with one long axis (a trajectory over time at one parameter point) then costs
    one vector-core product per core plus the long axis times one core's node count.
    """
    cores, order = fm.cores, fm.mode_order
    sizes = [mats[j].shape[0] for j in order]
    k = int(np.argmax(sizes))
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
