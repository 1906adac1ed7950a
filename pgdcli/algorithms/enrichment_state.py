"""The state of the PGD enrichment: the separated approximation and its images under the operator.

Shared by the enrichment's projection and update sweeps (:mod:`pgdcli.algorithms.enrichment`)
and the joint update of one mode (:mod:`pgdcli.algorithms.mode_update`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..tensors.cp import CPTensor, SeparatedOperator
from ..tensors.cp_sweep import separated_norm

__all__ = ["EnrichmentState"]


@dataclass
class EnrichmentState:
    """Current approximation ``U = sum_i alpha_i (x)_j U_j[:, i]`` and its images ``A_k U``."""

    op: SeparatedOperator
    source: CPTensor
    alphas: np.ndarray
    factors: list[np.ndarray]
    images: list[np.ndarray]  # images[j]: (K, m_j, n) = A_kj @ U_j
    # mode -> (images^T images, images^T source factors), until that mode changes (update_mode
    # needs them for every other mode, d - 1 times per update sweep)
    _products: dict = field(default_factory=dict, repr=False)
    # mode -> its update's block-Jacobi inverses, kept from one update sweep to the next
    preconditioners: dict = field(default_factory=dict, repr=False)

    @classmethod
    def empty(cls, op: SeparatedOperator, source: CPTensor) -> "EnrichmentState":
        sizes = [op.terms[0][j].shape for j in range(op.order)]
        return cls(
            op,
            source,
            np.zeros(0),
            [np.zeros((n, 0)) for _, n in sizes],
            [np.zeros((op.n_terms, m, 0)) for m, _ in sizes],
        )

    @property
    def rank(self) -> int:
        return self.alphas.size

    def append(self, columns: list[np.ndarray], alpha: float) -> None:
        self._products.clear()
        self.alphas = np.append(self.alphas, alpha)
        for j, col in enumerate(columns):
            self.factors[j] = np.column_stack([self.factors[j], col])
            stack = self.op.mode_stack(j)
            image = (stack.reshape(-1, stack.shape[2]) @ col).reshape(stack.shape[0], -1)
            self.images[j] = np.concatenate([self.images[j], image[:, :, None]], axis=2)

    def set_mode(self, j: int, factor: np.ndarray, image: np.ndarray | None = None) -> None:
        """Replace the factors of mode ``j`` (and their images, computed unless given)."""
        self._products.pop(j, None)
        self.factors[j] = factor
        if image is not None:
            self.images[j] = image
            return
        stack = self.op.mode_stack(j)
        self.images[j] = (stack.reshape(-1, stack.shape[2]) @ factor).reshape(stack.shape[0], stack.shape[1], -1)

    def residual_weights(self) -> np.ndarray:
        """Weights of ``F - A U``, shape (nF + K n,): the source's, then ``-alphas`` per operator term."""
        return np.concatenate([self.source.weights, -np.tile(self.alphas, self.op.n_terms)])

    def residual_columns(self, j: int) -> np.ndarray:
        """Mode ``j`` factors of ``F - A U``, shape (m_j, nF + K n): source columns, then images term-major."""
        image = self.images[j]
        return np.hstack([self.source.factors[j], image.transpose(1, 0, 2).reshape(image.shape[1], -1)])

    def residual(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """``F - A U`` as weights (C,) and factors (m_j, C); source columns first."""
        return self.residual_weights(), [self.residual_columns(j) for j in range(self.op.order)]

    def residual_norm(self) -> float:
        """``||F - A U||`` by an orthogonal sweep, accurate to rounding."""
        return separated_norm(*self.residual())

    def snapshot(self) -> tuple:
        """A copy of the weights, factors and images, for :meth:`restore`."""
        return self.alphas.copy(), [f.copy() for f in self.factors], [m.copy() for m in self.images]

    def restore(self, snapshot: tuple) -> None:
        self._products.clear()
        alphas, factors, images = snapshot
        self.alphas, self.factors, self.images = alphas, factors, images

    def image_products(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """Gram matrix of mode ``m``'s images, shape (K n, K n), and their products with the
        source's factors, shape (K n, nF); rows and columns term-major."""
        if m not in self._products:
            img = self.images[m].transpose(1, 0, 2).reshape(self.images[m].shape[1], -1)  # (m_m, K n)
            self._products[m] = (img.T @ img, img.T @ self.source.factors[m])
        return self._products[m]
