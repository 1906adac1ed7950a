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
evaluation per coordinate differentiated. The contractions are the evaluation's own
(:func:`~pgdcli.codebook.evaluate.contract_tt`, :func:`~pgdcli.codebook.evaluate.grid_tt`,
:func:`~pgdcli.codebook.evaluate.grid_cp`).

This module imports numpy only.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Sequence

import numpy as np

from ..discretization.basis import ChebyshevBasis, LinearBasis, PiecewiseChebyshevBasis, barycentric_rows
from ..tuning import CHUNK_VALUES
from .evaluate import contract_tt, grid_cp, grid_tt
from .fields import TT

__all__ = ["derivative_matrix", "gradient_points", "gradient_grid", "TrajectoryModel"]


def derivative_matrix(basis, x) -> np.ndarray:
    """Derivatives of the ``n`` cardinal functions of ``basis`` at points ``x``.

    Parameters
    ----------
    basis : pgdcli.discretization.basis.Basis1D
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
    """Each point's cardinal row on its slab times that slab's differentiation matrix (the unit
    slab's, scaled by ``2 / (b - a)``), placed at the slab's nodes: all points at once."""
    m = basis.slab_size
    slabs = basis.slab_of(x)
    idx = (slabs * (m - 1))[:, None] + np.arange(m)  # (p, m) global node indices of each point's slab
    bp = np.asarray(basis.breakpoints)
    rows = barycentric_rows(x, basis.nodes[idx], basis.bary) @ _unit_derivative(m)
    rows *= (2.0 / (bp[slabs + 1] - bp[slabs]))[:, None]
    out = np.zeros((x.size, basis.nodes.size))
    out[np.arange(x.size)[:, None], idx] = rows
    return out


@lru_cache(maxsize=16)
def _unit_derivative(m: int) -> np.ndarray:
    return ChebyshevBasis((-1.0, 1.0), m).derivative


def gradient_points(fields, bases, flat, wrt: Sequence[int], selected: Sequence[str]) -> dict:
    """Derivatives at points given coordinate by coordinate (already checked).

    Parameters
    ----------
    fields : mapping
        Unknown name -> ``CPTensor`` or ``TT``.
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
    size = flat[0].size if flat else 0
    block = max(1, CHUNK_VALUES // max(b.nodes.size for b in bases))
    if size > block:  # (P, n) rows per coordinate: a march's time basis has ~1e4-1e5 nodes
        parts = [gradient_points(fields, bases, [x[lo:lo + block] for x in flat], wrt, selected)
                 for lo in range(0, size, block)]
        return {u: [np.concatenate([p[u][k] for p in parts]) for k in range(len(wrt))] for u in selected}
    mats = [b.interpolation_matrix(x) for b, x in zip(bases, flat)]
    dmats = {j: derivative_matrix(bases[j], flat[j]) for j in wrt}
    out = {}
    for u in selected:
        fm = fields[u]
        if isinstance(fm, TT):
            out[u] = [contract_tt(fm, _swap(mats, j, dmats[j])) for j in wrt]
        else:
            vs = [m @ modes for m, modes in zip(mats, fm.factors)]  # (P, rank)
            out[u] = []
            for j in wrt:
                prod = dmats[j] @ fm.factors[j]
                for k, v in enumerate(vs):
                    if k != j:
                        prod = prod * v
                out[u].append(prod @ fm.weights)
    return out


def _swap(mats: list, j: int, replacement: np.ndarray) -> list:
    out = list(mats)
    out[j] = replacement
    return out


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
        grid = grid_tt if isinstance(fm, TT) else grid_cp
        out[u] = [grid(fm, m) for m in variants]
    return out


class TrajectoryModel:
    """Unknowns along one coordinate ("the axis", e.g. time at the data times) at varying points of the others.

    The axis's interpolation is done once; each call then costs one sweep over the other
    coordinates' cores (tensor trains) or modes (CP) at a single point, carrying the values
    and all requested derivatives together: what a least-squares fit needs per iteration.

    Parameters
    ----------
    codebook : Codebook
    axis : str
        The coordinate that takes many values.
    values : array_like, shape (P,)
        Its values (checked by the caller).
    fields : sequence of str
        Unknowns.
    """

    def __init__(self, codebook, axis: str, values, fields: Sequence[str]):
        names = codebook.coordinate_names
        self.axis = names.index(axis)
        self.bases = [c.basis() for c in codebook.coordinates]
        self.fields = [codebook.fields[u] for u in fields]
        rows = self.bases[self.axis].interpolation_matrix(np.asarray(values, dtype=float))
        # per unknown: the axis's modes (P, R) or its core contracted with the rows (P, r0, r1)
        self.axis_blocks = [rows @ fm.factors[self.axis] if not isinstance(fm, TT) else
                            np.tensordot(rows, fm.cores[list(fm.mode_order).index(self.axis)], axes=(1, 1))
                            for fm in self.fields]
        # tensor trains: each other core as (nodes, r0 * r1) (left of the axis) or (nodes, r1 * r0)
        # (right of it, transposed), so that weights times it is one matrix-vector product
        self.unfolded = []
        for fm in self.fields:
            if not isinstance(fm, TT):
                self.unfolded.append(None)
                continue
            k = list(fm.mode_order).index(self.axis)
            left = [(np.ascontiguousarray(c.transpose(1, 0, 2)).reshape(c.shape[1], -1), c.shape[0], c.shape[2], j)
                    for c, j in zip(fm.cores[:k], fm.mode_order[:k])]
            right = [(np.ascontiguousarray(c.transpose(1, 2, 0)).reshape(c.shape[1], -1), c.shape[2], c.shape[0], j)
                     for c, j in zip(fm.cores[:k:-1], fm.mode_order[:k:-1])]
            self.unfolded.append((left, right))

    def evaluate(self, point: Sequence[float], wrt: Sequence[int] = ()) -> np.ndarray:
        """Values and derivatives at ``point`` (a value per coordinate; the axis's entry is ignored).

        Returns
        -------
        ndarray, shape (fields, P, 1 + len(wrt))
            ``[..., 0]`` the values, ``[..., 1 + i]`` the derivatives with respect to coordinate ``wrt[i]``.
        """
        if self.axis in wrt:
            raise ValueError("a TrajectoryModel differentiates with respect to the other coordinates only")
        weights, dweights = {}, {}
        for j, (b, x) in enumerate(zip(self.bases, point)):
            if j != self.axis:
                weights[j] = b.interpolation_matrix(np.array([float(x)]))[0]
        for j in wrt:
            dweights[j] = derivative_matrix(self.bases[j], np.array([float(point[j])]))[0]
        slot = {j: 1 + i for i, j in enumerate(wrt)}
        stacked = {j: np.array([weights[j], dweights[j]]) for j in wrt}
        return np.stack([self._cp(fm, blk, weights, dweights, wrt) if unf is None else
                         self._tt(unf, blk, weights, stacked, slot)
                         for fm, blk, unf in zip(self.fields, self.axis_blocks, self.unfolded)])

    def _cp(self, fm, block, weights, dweights, wrt) -> np.ndarray:
        v = {j: w @ fm.factors[j] for j, w in weights.items()}
        cols = [fm.weights.copy()] + [fm.weights * (dweights[j] @ fm.factors[j]) for j in wrt]
        for j, vj in v.items():
            for i, col in enumerate(cols):
                if i == 0 or wrt[i - 1] != j:
                    col *= vj
        return block @ np.stack(cols, axis=1)

    def _tt(self, unfolded, block, weights, stacked, slot) -> np.ndarray:
        variants = 1 + len(slot)
        ends = []
        for cores in unfolded:  # the cores left of the axis, then those right of it (transposed)
            vec = np.ones((variants, 1))
            for mat, r0, r1, j in cores:
                if j in slot:  # the variant differentiating this core's coordinate: both rows in one pass
                    both = (stacked[j] @ mat).reshape(2, r0, r1)
                    out = vec @ both[0]
                    i = slot[j]
                    out[i] = vec[i] @ both[1]
                else:
                    out = vec @ (weights[j] @ mat).reshape(r0, r1)
                vec = out
            ends.append(vec)
        left, right = ends  # (variants, r0), (variants, r1)
        p, r0, r1 = block.shape
        tmp = (block.reshape(p * r0, r1) @ right.T).reshape(p, r0, variants)  # (P, r0, variants)
        return np.einsum("pav,va->pv", tmp, left)
