"""Exact ANOVA terms of a separated function: quadrature per coordinate, contracted through the cores.

For ``u(x) = sum_r alpha_r prod_j U_jr(x_j)`` (CP) or a tensor train, with independent random inputs
``x_j`` (a quadrature each: points and weights), split every coordinate's functions into their mean
and a centered part, ``U_j = mu_j + (U_j - mu_j)``. Expanding the product gives the ANOVA
(Hoeffding-Sobol) decomposition, and the variance of the term of a set ``S`` of inputs is a
quadratic form in the cores: per coordinate one of three ``rank x rank`` kernels,

- ``Q``: the product of the means (the coordinate is averaged out),
- ``C``: the covariance of the centered functions (the coordinate is in the set),
- ``P = Q + C``: the raw second moment (the coordinate may or may not be),

so that ``D_i`` (first order) is ``C`` at ``i`` and ``Q`` elsewhere, the total effect
``sum_{S ∋ i} D_S`` is ``C`` at ``i`` and ``P`` elsewhere, ``D_ij`` is ``C`` at ``i, j`` and ``Q``
elsewhere, and the variance is the chain ``sum_i [Q before i, C at i, P after i]`` (the law of
total variance, one input at a time). Every term is a sum of nonnegative quadratic forms of
centered values: no variance is found as a difference of second moments, so small variances
keep their digits.

CP: the kernels are ``rank x rank`` matrices combined by Hadamard products (cost ``d n r^2``).
Tensor train: they are transfer maps on ``r x r`` environments, contracted from both ends toward
the time core (cost ``d n r^3`` a pattern, environments shared between patterns). The time
coordinate (and coordinates held fixed) enter through their interpolation rows: a batch of
times costs one small product each at the end.

numpy only.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .fields import TT

__all__ = ["Patterns", "cp_terms", "tt_terms", "cp_patterns", "tt_patterns"]


class Patterns:
    """The kernel patterns of the requested quantities, over ``d`` inputs (letters ``Q``, ``C``, ``P``).

    Attributes
    ----------
    first, total : list of str
        Per input.
    chain : list of str
        The variance's terms (their sum is the variance).
    second : list of (int, int, str)
        Per pair ``i < j`` (empty unless asked).
    """

    def __init__(self, d: int, second_order: bool):
        self.d = d
        self.first = ["Q" * i + "C" + "Q" * (d - i - 1) for i in range(d)]
        self.total = ["P" * i + "C" + "P" * (d - i - 1) for i in range(d)]
        self.chain = ["Q" * i + "C" + "P" * (d - i - 1) for i in range(d)]
        self.second = []
        if second_order:
            for i in range(d):
                for j in range(i + 1, d):
                    letters = ["Q"] * d
                    letters[i] = letters[j] = "C"
                    self.second.append((i, j, "".join(letters)))

    def all(self) -> list[str]:
        return sorted(set(self.first + self.total + self.chain + [s for _, _, s in self.second]))


def _results(patterns: Patterns, value, mean) -> dict:
    """Evaluate every pattern (``value(letters) -> (T,)``) into the result arrays."""
    d = patterns.d
    cache = {p: value(p) for p in patterns.all()}
    out = {"mean": mean,
           "variance": sum((cache[p] for p in patterns.chain), np.zeros_like(mean)),
           "first": np.stack([cache[p] for p in patterns.first], axis=-1) if d else np.zeros(mean.shape + (0,)),
           "total": np.stack([cache[p] for p in patterns.total], axis=-1) if d else np.zeros(mean.shape + (0,))}
    if patterns.second:
        second = np.zeros(mean.shape + (d, d))
        for i, j, p in patterns.second:
            second[..., i, j] = second[..., j, i] = cache[p]
        out["second"] = second
    return out


# ----------------------------------------------------------------------------------------------
# CP: Hadamard products of rank x rank kernels
# ----------------------------------------------------------------------------------------------
def cp_terms(alphas: np.ndarray, modes: Sequence[np.ndarray], random: dict, rows: dict, batch: tuple | None,
             patterns: Patterns, cache: dict | None = None) -> dict:
    """ANOVA terms of a CP field.

    Parameters
    ----------
    alphas : ndarray, shape (r,)
    modes : sequence of ndarray, each (n_j, r)
        Nodal modes per coordinate.
    random : dict
        Input index (0..d-1) -> (coordinate index, B (Q, n_j) interpolation rows at the quadrature
        points or None for the nodes themselves, w (Q,) weights summing to 1).
    rows : dict
        Fixed coordinate index -> its interpolation row (n_j,).
    batch : (int, ndarray (T, n)) or None
        The batched coordinate (time) and its rows at the T values.
    patterns : Patterns

    Returns
    -------
    dict
        ``mean`` and ``variance`` (T,), ``first`` and ``total`` (T, d), ``second`` (T, d, d) if asked:
        the terms' variances (not yet divided by the variance).
    """
    value, mean = cp_patterns(alphas, modes, random, rows, batch, cache)
    return _results(patterns, value, mean)


def cp_patterns(alphas, modes, random: dict, rows: dict, batch: tuple | None, cache: dict | None = None):
    """``(value, mean)``: ``value(letters) -> (T,)`` the quadratic form of a kernel pattern (one letter
    per input), and the mean (T,), of a CP field (arguments as :func:`cp_terms`). ``cache``: the
    kernels of an input, kept between calls on the same modes and quadrature."""
    cache = {} if cache is None else cache
    scale = np.array(alphas, dtype=float)
    for j, row in rows.items():
        scale = scale * (row @ modes[j])
    beta = scale[None, :] if batch is None else scale[None, :] * (batch[1] @ modes[batch[0]])  # (T, r)
    kernels = []
    mean_product = np.ones_like(scale)
    for i in range(len(random)):
        j, b, w = random[i]
        key = (id(modes[j]), id(b), id(w))
        if key not in cache:
            values = modes[j] if b is None else b @ modes[j]  # (Q, r): the modes at the quadrature points
            mu = w @ values
            centered = (values - mu) * np.sqrt(w)[:, None]
            cov = centered.T @ centered
            outer = np.outer(mu, mu)
            cache[key] = ({"Q": outer, "C": cov, "P": outer + cov}, mu)
        kernel, mu = cache[key]
        kernels.append(kernel)
        mean_product = mean_product * mu

    def value(letters: str) -> np.ndarray:
        h = None
        for kernel, letter in zip(kernels, letters):
            h = kernel[letter] if h is None else h * kernel[letter]
        if h is None:
            h = np.ones((beta.shape[1], beta.shape[1]))
        return np.einsum("tr,tr->t", beta @ h, beta)

    return value, beta @ mean_product


# ----------------------------------------------------------------------------------------------
# tensor train: transfer maps on environments
# ----------------------------------------------------------------------------------------------
class _Core:
    """One core's parts: its matrix at a fixed value, or its mean and weighted centered slices."""

    def __init__(self, core: np.ndarray, kind: str, data):
        self.kind = kind  # 'fixed' | 'random' | 'batch'
        if kind == "fixed":
            self.matrix = np.tensordot(data, core, axes=(0, 1))  # (r0, r1)
        elif kind == "random":
            b, w = data
            slices = np.moveaxis(core, 1, 0) if b is None else np.tensordot(b, core, axes=(1, 1))  # (Q, r0, r1)
            self.matrix = np.tensordot(w, slices, axes=(0, 0))  # the mean core
            self.centered = (slices - self.matrix) * np.sqrt(w)[:, None, None]  # (Q, r0, r1)
            # the same, (r0, Q r1): the right transfer as two matrix products
            self.by_row = np.ascontiguousarray(self.centered.transpose(1, 0, 2)).reshape(core.shape[0], -1)
        else:
            self.batch = np.tensordot(data, core, axes=(1, 1))  # (T, r0, r1)

    def left(self, phi: np.ndarray, letter: str) -> np.ndarray:
        """``Phi (r0, r0) -> (r1, r1)``: this core contracted on both sides of the environment."""
        if self.kind == "fixed" or letter in "QP":
            a = self.matrix
            mean = a.T @ phi @ a
            if self.kind == "fixed" or letter == "Q":
                return mean
        h = self.centered
        k = np.matmul(phi, h)  # (Q, r0, r1)
        cov = h.reshape(-1, h.shape[2]).T @ k.reshape(-1, k.shape[2])
        return mean + cov if letter == "P" else cov

    def right(self, psi: np.ndarray, letter: str) -> np.ndarray:
        """``Psi (r1, r1) -> (r0, r0)``."""
        if self.kind == "fixed" or letter in "QP":
            a = self.matrix
            mean = a @ psi @ a.T
            if self.kind == "fixed" or letter == "Q":
                return mean
        h = self.by_row  # (r0, Q r1)
        k = (h.reshape(-1, psi.shape[0]) @ psi).reshape(h.shape)
        cov = k @ h.T
        return mean + cov if letter == "P" else cov


def tt_terms(fm: TT, random: dict, rows: dict, batch: tuple | None, patterns: Patterns,
             cache: dict | None = None) -> dict:
    """ANOVA terms of a tensor-train field (arguments and result as :func:`cp_terms`)."""
    value, mean = tt_patterns(fm, random, rows, batch, cache)
    return _results(patterns, value, mean)


def tt_patterns(fm: TT, random: dict, rows: dict, batch: tuple | None, cache: dict | None = None):
    """:func:`cp_patterns` of a tensor-train field."""
    cache = {} if cache is None else cache
    slot = {j: i for i, (j, _, _) in random.items()}  # coordinate -> input index
    cores, kinds = [], []
    for core, j in zip(fm.cores, fm.mode_order):
        if j in slot:
            _, b, w = random[slot[j]]
            key = (id(core), id(b), id(w))
            if key not in cache:
                cache[key] = _Core(core, "random", (b, w))
            cores.append(cache[key])
        elif batch is not None and j == batch[0]:
            cores.append(_Core(core, "batch", batch[1]))
        else:
            cores.append(_Core(core, "fixed", rows[j]))
        kinds.append(slot.get(j))
    pivot = next((k for k, c in enumerate(cores) if c.kind == "batch"), len(cores))
    left_cache: dict = {(): np.ones((1, 1))}
    right_cache: dict = {(): np.ones((1, 1))}

    def letters_of(letters: str, span: range) -> tuple:
        return tuple(letters[kinds[k]] if kinds[k] is not None else "F" for k in span)

    def left(key: tuple) -> np.ndarray:
        if key not in left_cache:
            left_cache[key] = cores[len(key) - 1].left(left(key[:-1]), key[-1])
        return left_cache[key]

    def right(key: tuple) -> np.ndarray:  # key: letters of cores pivot+1.., read from the far end
        if key not in right_cache:
            right_cache[key] = cores[len(cores) - len(key)].right(right(key[1:]), key[0])
        return right_cache[key]

    def value(letters: str) -> np.ndarray:
        phi = left(letters_of(letters, range(pivot)))
        if pivot == len(cores):
            return phi.reshape(1)
        psi = right(letters_of(letters, range(pivot + 1, len(cores))))
        a = cores[pivot].batch  # (T, r0, r1)
        return np.einsum("tab,tab->t", a, np.matmul(np.matmul(phi, a), psi))

    lvec = np.ones((1, 1))
    for c in cores[:pivot]:
        lvec = lvec @ c.matrix
    rvec = np.ones((1, 1))
    for c in cores[:pivot:-1]:
        rvec = c.matrix @ rvec
    if pivot == len(cores):
        mean = lvec.reshape(1)
    else:
        mean = np.einsum("a,tab,b->t", lvec[0], cores[pivot].batch, rvec[:, 0])
    return value, mean
