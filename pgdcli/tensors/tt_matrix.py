"""Linear operators in tensor-train form (TT-matrices, Oseledets 2010).

A TT-matrix of order ``d`` is

    A[(i_1, ..., i_d), (j_1, ..., j_d)] = C_1[:, i_1, j_1, :] @ C_2[:, i_2, j_2, :] @ ... @ C_d[:, i_d, j_d, :]

with cores ``C_k`` of shape ``(R_{k-1}, m_k, n_k, R_k)``, ``R_0 = R_d = 1``. A *diagonal* mode
(every ``C_k[:, i, j, :]`` zero off ``i = j``: a collocated parameter) keeps only its diagonal,
a core of shape ``(R_{k-1}, n_k, R_k)``: products and local solves then cost ``n_k`` instead of
``n_k^2`` per rank pair. A sum of Kronecker products (:class:`pgdcli.tensors.cp.SeparatedOperator`)
becomes a TT-matrix by the TT-SVD of its terms (:func:`tt_matrix_from_terms`), whose ranks are
those of the operator's unfoldings, usually far fewer than its terms.

numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .cp_sweep import separated_norm
from .tt import TT, tt_round
from .tt_svd import tt_from_cp

__all__ = ["TTMatrix", "tt_matrix_from_terms"]

#: Relative Frobenius bound of the compression of an operator's terms: rounding level, so the
#: TT-matrix is the operator (linearly dependent terms merged, nothing else dropped).
OPERATOR_ROUNDING = 1e-14


@dataclass(frozen=True, eq=False)
class TTMatrix:
    """A tensor-train matrix.

    Parameters
    ----------
    cores : sequence of ndarray
        ``cores[k]`` of shape ``(R_{k-1}, m_k, n_k, R_k)``, or ``(R_{k-1}, n_k, R_k)`` for a
        diagonal mode; ``R_0 = R_d = 1``.
    """

    cores: tuple[np.ndarray, ...]

    def __init__(self, cores: Sequence[np.ndarray]):
        cs = tuple(np.asarray(c, dtype=float) for c in cores)
        if not cs:
            raise ValueError("a TT-matrix needs at least one core")
        for k, c in enumerate(cs):
            if c.ndim not in (3, 4):
                raise ValueError(f"core {k} must be (R_{k}, m, n, R_{k + 1}) or diagonal (R_{k}, n, R_{k + 1}), "
                                 f"got shape {c.shape}")
            if k and c.shape[0] != cs[k - 1].shape[-1]:
                raise ValueError(f"core {k} has left rank {c.shape[0]}, core {k - 1} right rank {cs[k - 1].shape[-1]}")
        if cs[0].shape[0] != 1 or cs[-1].shape[-1] != 1:
            raise ValueError("the first core's left rank and the last core's right rank must be 1")
        object.__setattr__(self, "cores", cs)

    @property
    def order(self) -> int:
        return len(self.cores)

    @property
    def ranks(self) -> tuple[int, ...]:
        """Inner ranks ``(R_1, ..., R_{d-1})``."""
        return tuple(c.shape[-1] for c in self.cores[:-1])

    @property
    def row_shape(self) -> tuple[int, ...]:
        return tuple(c.shape[1] for c in self.cores)

    @property
    def column_shape(self) -> tuple[int, ...]:
        return tuple(c.shape[1] if c.ndim == 3 else c.shape[2] for c in self.cores)

    def diagonal(self, k: int) -> bool:
        """Whether mode ``k`` is stored as its diagonal."""
        return self.cores[k].ndim == 3

    def dense_core(self, k: int) -> np.ndarray:
        """Core ``k`` as ``(R_{k-1}, m_k, n_k, R_k)`` (a diagonal one expanded)."""
        c = self.cores[k]
        if c.ndim == 4:
            return c
        out = np.zeros((c.shape[0], c.shape[1], c.shape[1], c.shape[2]))
        idx = np.arange(c.shape[1])
        out[:, idx, idx, :] = c
        return out

    def full(self) -> np.ndarray:
        """The full matrix, rows and columns in C order of the modes (small operators only: tests)."""
        out = np.ones((1, 1, 1))
        for k in range(self.order):
            c = self.dense_core(k)
            out = np.einsum("mnr,rijs->minjs", out, c)
            out = out.reshape(out.shape[0] * out.shape[1], out.shape[2] * out.shape[3], -1)
        return out[:, :, 0]

    def matvec(self, x: TT) -> TT:
        """``A x`` as a tensor train of ranks ``R_k r_k`` (exact; round afterwards)."""
        cores = []
        for k, (a, c) in enumerate(zip(self.cores, x.cores)):
            ra, rb = a.shape[0], a.shape[-1]
            r0, n, r1 = c.shape
            if a.ndim == 3:
                out = a[:, None, :, :, None] * c[None, :, :, None, :]  # (ra, r0, n, rb, r1)
            else:
                out = np.tensordot(a, c, axes=(2, 1))  # (ra, m, rb, r0, r1)
                out = out.transpose(0, 3, 1, 2, 4)
            cores.append(out.reshape(ra * r0, out.shape[2], rb * r1))
        return TT(cores)

    def transpose(self) -> "TTMatrix":
        return TTMatrix([c if c.ndim == 3 else c.transpose(0, 2, 1, 3) for c in self.cores])

    def gram(self) -> "TTMatrix":
        """``A^T A``, ranks ``R_k^2`` before rounding (a diagonal mode stays diagonal)."""
        cores = []
        for a in self.cores:
            ra, rb = a.shape[0], a.shape[-1]
            if a.ndim == 3:
                g = a[:, None, :, :, None] * a[None, :, :, None, :]  # (ra, ra', n, rb, rb')
                cores.append(g.reshape(ra * ra, a.shape[1], rb * rb))
            else:
                g = np.einsum("pmiq,smjt->psijqt", a, a)
                cores.append(g.reshape(ra * ra, a.shape[2], a.shape[2], rb * rb))
        return TTMatrix(cores)

    def rounded(self, relative: float = OPERATOR_ROUNDING) -> "TTMatrix":
        """The same operator with the smallest ranks within a relative Frobenius bound."""
        shapes = [c.shape for c in self.cores]
        vectors = TT([c.reshape(c.shape[0], -1, c.shape[-1]) for c in self.cores])
        rounded = tt_round(vectors, relative)
        return TTMatrix([c.reshape((c.shape[0],) + s[1:-1] + (c.shape[2],))
                         for c, s in zip(rounded.cores, shapes)])

    def scaled_columns(self, scales: Sequence[np.ndarray]) -> "TTMatrix":
        """``A diag(s_1 (x) ... (x) s_d)``: column ``j_k`` of mode ``k`` times ``scales[k][j_k]``."""
        cores = []
        for c, s in zip(self.cores, scales):
            s = np.asarray(s, dtype=float)
            cores.append(c * s[None, :, None] if c.ndim == 3 else c * s[None, None, :, None])
        return TTMatrix(cores)


def tt_matrix_from_terms(terms: Sequence[Sequence[np.ndarray]], relative: float = OPERATOR_ROUNDING) -> TTMatrix:
    """The TT-matrix of a sum of Kronecker products ``sum_t A_t1 (x) ... (x) A_td``.

    A mode whose matrices are all diagonal is stored as its diagonal. The terms are
    compressed by the TT-SVD of their sum (:func:`pgdcli.tensors.tt_svd.tt_from_cp`, no Gram
    products) to ``relative`` times the operator's Frobenius norm.

    Parameters
    ----------
    terms : sequence of sequence of ndarray
        ``terms[t][k]`` of shape (m_k, n_k), the same for every term.
    relative : float

    Returns
    -------
    TTMatrix
    """
    d = len(terms[0])
    shapes = [np.shape(terms[0][k]) for k in range(d)]
    diagonal = []
    factors = []
    for k in range(d):
        mats = [np.asarray(t[k], dtype=float) for t in terms]
        square = shapes[k][0] == shapes[k][1]
        diag = square and all(not np.any(m - np.diag(np.diag(m))) for m in mats)
        diagonal.append(diag)
        factors.append(np.column_stack([np.diag(m) if diag else m.reshape(-1) for m in mats]))
    weights = np.ones(len(terms))
    train = tt_from_cp(weights, factors, relative * separated_norm(weights, factors))
    cores = []
    for k, c in enumerate(train.cores):
        shape = (c.shape[0], shapes[k][0], c.shape[2]) if diagonal[k] else (c.shape[0],) + shapes[k] + (c.shape[2],)
        cores.append(c.reshape(shape))
    return TTMatrix(cores)
