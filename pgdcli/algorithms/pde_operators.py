"""The two parts of the split PDE system on the whole grid: the diffusion's phi-functions and ``N(t, u)``.

:class:`DenseOperators` holds the state of every species as one array ``(q, m_x, [m_y], n_p...)``
(interior values) and implements what the exponential schemes of :mod:`.pde_march` ask:

* ``phi(h)``: the scheme's coefficients, ``phi_k`` of ``h L_s`` with ``L_s = sum_a c_sa A_sa``, as
  arrays in the eigenbasis of the ``A_sa``: their Kronecker sum has the eigenvectors ``V_x (x) V_y``
  and the eigenvalues ``c_x lambda_i + c_y mu_j`` at every parameter node, so a phi-function of it
  is one array of scalars (:func:`.pde_phi.phi_scalars`) between two changes of basis along each
  space axis;
* ``apply(F, w)``: ``V (F * (V^-1 w))`` per species;
* ``nonlinear(w, t)``: ``N_s`` on the interior nodes, every monomial evaluated pointwise
  (derivatives by the Chebyshev differentiation matrices along their axis, functions of the
  unknowns by their expression trees), plus the lift's diffusion.

The tensor-train counterpart is :class:`.pde_train.TrainOperators`.
"""

from __future__ import annotations

import numpy as np

from ..errors import SolverError
from ..problem.general import evaluate as evaluate_tree
from ..tensors.cross import tt_from_full
from .pde_boundary import mode_product
from .pde_phi import phi_scalars
from .pde_system import PdeSystem

__all__ = ["DenseOperators", "etd_coefficients", "cached_coefficients", "eigenvalues", "tail_rows"]

#: phi-function caches kept (a step's sizes: h, h/2 and the inner slab nodes' fractions).
CACHE_SIZE = 10


def tail_rows(n: int) -> np.ndarray:
    """Rows mapping values at the n Chebyshev-Lobatto nodes (ascending) to the last two coefficients."""
    x = -np.cos(np.pi * np.arange(n) / (n - 1))
    return np.linalg.inv(np.polynomial.chebyshev.chebvander(x, n - 1))[-2:]


def etd_coefficients(z: np.ndarray, h: float) -> dict:
    """The ETDRK4 (Cox & Matthews) and Lawson coefficients at the eigenvalues ``z`` of ``h L`` (any shape)."""
    full = phi_scalars(z, 3)
    half = phi_scalars(0.5 * z, 1)
    if not np.iscomplexobj(z):
        full, half = full.real, half.real
    return {"E": full[0], "E2": half[0], "Q": 0.5 * h * half[1],
            "b1": h * (full[1] - 3 * full[2] + 4 * full[3]), "b23": h * (2 * full[2] - 4 * full[3]),
            "b4": h * (4 * full[3] - full[2])}


def cached_coefficients(cache: dict, spectra: list, h: float) -> dict:
    """:func:`etd_coefficients` of ``h`` times each species' ``spectra``, name -> list per species, kept in
    ``cache`` (the last :data:`CACHE_SIZE` step sizes)."""
    key = float(h)
    if key not in cache:
        if len(cache) >= CACHE_SIZE:
            cache.pop(next(iter(cache)))
        per = [etd_coefficients(h * z, h) for z in spectra]
        cache[key] = {name: [p[name] for p in per] for name in per[0]}
    return cache[key]


def eigenvalues(system: PdeSystem, s: int) -> np.ndarray:
    """``sum_a c_sa lambda_a`` on the interior grid in the eigenbasis (broadcastable)."""
    sp = system.species[s]
    total = 0.0
    for a, (eig, c) in enumerate(zip(sp.eigen, sp.diffusion)):
        if eig.Vinv is None:
            raise SolverError(f"the eliminated second derivative along {system.modes[a]} has ill-conditioned "
                              f"eigenvectors (condition {eig.condition:.2g})")
        lam = eig.lam.reshape([-1 if j == a else 1 for j in range(len(system.modes))])
        total = total + c * lam
    return total


class DenseOperators:
    """The split system's operations on whole-grid arrays (see the module docstring)."""

    def __init__(self, system: PdeSystem) -> None:
        self.s = system
        self.q = len(system.species)
        self.size = float(self.q * np.prod(system.shape))
        self.D2 = [D @ D for D in system.D1]
        self.spectra = [eigenvalues(system, s) for s in range(self.q)]
        self.cache: dict = {}
        self.evaluations = 0
        self._tails = [tail_rows(n) for n in system.shape[:system.space]]

    # -- state ------------------------------------------------------------------------------------
    def initial(self) -> np.ndarray:
        return self.s.initial.copy()

    def full(self, w: np.ndarray) -> list:
        """``u_s`` on the full grid, per species."""
        out = []
        for s, sp in enumerate(self.s.species):
            u = w[s]
            for a, Z in enumerate(sp.Z):
                u = mode_product(Z, u, a)
            out.append(u + sp.lift)
        return out

    @staticmethod
    def combine(terms, weights, delta: float) -> np.ndarray:
        return sum(b * t for t, b in zip(terms, weights))

    @staticmethod
    def norm(w: np.ndarray) -> float:
        return float(np.linalg.norm(w))

    @staticmethod
    def rank(w) -> int:
        return 0

    @staticmethod
    def tighten() -> bool:
        return False  # nothing is rounded

    def states(self, w: np.ndarray, delta: float) -> list:
        """``u_s`` per species as tensor trains over the full nodes, each within ``delta`` (Frobenius)."""
        return [tt_from_full(np.ascontiguousarray(u), delta) for u in self.full(w)]

    def tail(self, w: np.ndarray, axes) -> tuple:
        """``(axis, tail)``: of the space ``axes``, the one with the largest Chebyshev tail of ``u`` (RMS over the
        other nodes of the larger of its last two coefficients, the largest over the species)."""
        worst = (axes[0], 0.0)
        for u in self.full(w):
            for a in axes:
                rows = self._tails[a]
                coef = np.abs(mode_product(rows, u, a)).max(axis=a)
                tail = float(np.sqrt(np.mean(coef * coef)))
                worst = max(worst, (a, tail), key=lambda p: p[1])
        return worst

    # -- the explicit part ------------------------------------------------------------------------
    def nonlinear(self, w: np.ndarray, t: float, delta: float = 0.0) -> np.ndarray:
        """``N(t, u)`` on the interior nodes, shape of ``w``."""
        self.evaluations += 1
        U = self.full(w)
        atoms: dict = {}
        values = None
        out = np.empty_like(w)
        for s, sp in enumerate(self.s.species):
            total = np.broadcast_to(sp.source, w.shape[1:]).copy()
            for term in sp.terms:
                product = self.s.coefficient(s, term, t)
                for atom in term.atoms:
                    if atom[0] == "g":
                        if values is None:
                            values = {**self.s.values(t), **{sp2.name: U[k] for k, sp2 in enumerate(self.s.species)}}
                        value = evaluate_tree(atom[1], values)
                    else:
                        value = self._atom(atoms, U, atom)
                    product = product * value
                total += np.broadcast_to(product, U[s].shape)[self.s.interior]
            out[s] = total
        return out

    def _atom(self, cache: dict, U: list, atom: tuple) -> np.ndarray:
        _, k, axis, order = atom
        if order == 0:
            return U[k]
        if atom not in cache:
            cache[atom] = mode_product(self.s.D1[axis] if order == 1 else self.D2[axis], U[k], axis)
        return cache[atom]

    # -- the diffusion ----------------------------------------------------------------------------
    def phi(self, h: float) -> dict:
        """The scheme's coefficients for a step ``h``: name -> list (per species) of arrays in the eigenbasis."""
        return cached_coefficients(self.cache, self.spectra, h)

    def apply(self, F: list, w: np.ndarray, delta: float = 0.0) -> np.ndarray:
        """``V_s (F_s * (V_s^-1 w_s))`` for every species."""
        out = np.empty_like(w)
        for s, sp in enumerate(self.s.species):
            X = w[s]
            for a, eig in enumerate(sp.eigen):
                X = mode_product(eig.Vinv, X, a)
            X = X * F[s]
            for a, eig in enumerate(sp.eigen):
                X = mode_product(eig.V, X, a)
            out[s] = X
        return out
