"""The split PDE system's operations on tensor trains (grids too large for :class:`.pde_operators.DenseOperators`).

Each species' interior state is a tensor train over ``(x, [y], parameters)``, the parameters the
diffusion depends on first (:class:`.pde_structure.PdeStructure`). The operations of
:mod:`.pde_march`'s schemes:

* a phi-function of the diffusion acts on the first ``K`` modes (the space axes and the diffusion's
  parameters) merged into one supercore: a change of basis along each space axis into the
  eigenvectors, the product with the array of scalar phi-values (:mod:`.pde_operators`), the change
  back, and the supercore split again by truncated SVDs (or on the ``x`` core alone when ``K = 1``);
* ``N_s``: the polynomial monomials by Hadamard products (rounded), the derivatives by the
  differentiation matrices on their space core, the coefficients compressed from the grid (TT-SVD,
  once when they do not depend on time); the monomials holding a function of the unknowns by one
  TT-cross per species (:func:`pgdcli.tensors.cross.tt_cross`) from the trains' entries.
"""

from __future__ import annotations

import numpy as np

from ..problem.general import evaluate as evaluate_tree
from ..tensors.cross import tt_cross, tt_from_full, tt_point_function
from ..tensors.tt import TT, tt_hadamard, tt_round, tt_sum
from ..tensors.tt_svd import thin_svd, truncation_rank
from .pde_boundary import mode_product
from .pde_operators import cached_coefficients, eigenvalues
from .pde_system import PdeSystem

__all__ = ["TrainOperators"]

#: Relative accuracy of the compressed initial values, lifts and coefficients.
EXACT = 1e-13
#: Cap on the ranks of the cross of a species' functions of the unknowns.
CROSS_MAX_RANK = 200
#: Share of a step's rounding budget given to each rounding of a stage (ETDRK4 with step doubling
#: rounds ~16 times per step; their errors add up): a larger share made the step-doubling estimate
#: the roundings' noise (2-D Fisher on 49 x 49 x 5 x 5 nodes: half the error allowed at any step size,
#: the steps shrinking to nothing).
OPERATION_SHARE = 0.1
#: Most tightenings of the share (10x each) when the step-doubling estimate is the roundings' noise.
MAX_TIGHTENINGS = 3


def _on_mode(train: TT, M: np.ndarray, k: int) -> TT:
    """``M`` applied along mode ``k``."""
    cores = list(train.cores)
    cores[k] = np.einsum("ij,ajb->aib", M, cores[k])
    return TT(cores)


def _compressed(values: np.ndarray, shape: tuple) -> TT:
    full = np.ascontiguousarray(np.broadcast_to(values, shape), dtype=float)
    return tt_from_full(full, EXACT * max(float(np.linalg.norm(full)), 1e-300))


class TrainOperators:
    """The operations of :class:`.pde_operators.DenseOperators` on lists of tensor trains (one per species)."""

    def __init__(self, system: PdeSystem) -> None:
        self.s = system
        self.q = len(system.species)
        self.size = float(self.q * np.prod(system.shape))
        self.K = system.diffusion_modes
        self.D2 = [D @ D for D in system.D1]
        self.lifts = [_compressed(sp.lift, system.shape) for sp in system.species]
        self.sources = [_compressed(sp.source, system.interior_shape) for sp in system.species]
        head = system.interior_shape[:self.K]
        self.spectra = []
        for s in range(self.q):
            z = eigenvalues(system, s)  # varies along the first K modes only
            self.spectra.append(np.broadcast_to(z.reshape(z.shape[:self.K]), head))
        self.cache: dict = {}
        self.coefficients: dict = {}
        self.right_sets: dict = {}
        self.evaluations = 0
        self.share, self.tightenings = OPERATION_SHARE, 0

    def tighten(self) -> bool:
        """Round every operation 10x tighter (at most :data:`MAX_TIGHTENINGS` times); False when no more."""
        if self.tightenings >= MAX_TIGHTENINGS:
            return False
        self.share *= 0.1
        self.tightenings += 1
        return True

    def initial(self) -> list:
        return [_compressed(w, self.s.interior_shape) for w in self.s.initial]

    def full(self, w: list) -> list:
        out = []
        for s, sp in enumerate(self.s.species):
            u = w[s]
            for a, Z in enumerate(sp.Z):
                u = _on_mode(u, Z, a)
            out.append(tt_sum([u, self.lifts[s]]))
        return out

    def combine(self, terms, weights, delta: float) -> list:
        out = []
        for parts in zip(*terms):
            total = tt_sum(list(parts), list(weights))
            out.append(tt_round(total, absolute=self.share * delta / np.sqrt(self.q)) if delta > 0 else total)
        return out

    @staticmethod
    def norm(w: list) -> float:
        return float(np.sqrt(sum(x.norm() ** 2 for x in w)))

    @staticmethod
    def rank(w: list) -> int:
        return max(max(x.ranks, default=1) for x in w)

    def states(self, w: list, delta: float) -> list:
        return [tt_round(u, absolute=delta) for u in self.full(w)]

    @staticmethod
    def tail(w, axes) -> tuple:
        return axes[0], 0.0  # not watched on trains: the gate measures the codebook's

    # -- the explicit part ------------------------------------------------------------------------
    def _coefficient(self, s: int, term, t: float) -> TT:
        key = id(term)
        if term.steady and key in self.coefficients:
            return self.coefficients[key]
        train = _compressed(self.s.coefficient(s, term, t), self.s.shape)
        if term.steady:
            self.coefficients[key] = train
        return train

    def nonlinear(self, w: list, t: float, delta: float = 0.0) -> list:
        """``N_s(t, u)`` on the interior nodes per species, each rounded to the Frobenius ``delta``."""
        self.evaluations += 1
        delta = self.share * delta
        U = self.full(w)
        atoms: dict = {}
        out = []
        for s, sp in enumerate(self.s.species):
            parts = [self.sources[s]]
            general = [term for term in sp.terms if any(a[0] == "g" for a in term.atoms)]
            for term in sp.terms:
                if any(a[0] == "g" for a in term.atoms):
                    continue
                product = self._coefficient(s, term, t)
                for atom in term.atoms:
                    product = tt_round(tt_hadamard(product, self._atom(atoms, U, atom)), absolute=0.1 * delta)
                parts.append(self._interior(product))
            if general:
                parts.append(self._cross(s, general, U, atoms, t, delta))
            out.append(tt_round(tt_sum(parts), absolute=delta / np.sqrt(self.q)))
        return out

    def _interior(self, train: TT) -> TT:
        cores = list(train.cores)
        for a in range(self.s.space):
            cores[a] = cores[a][:, 1:-1, :]
        return TT(cores)

    def _atom(self, cache: dict, U: list, atom: tuple) -> TT:
        _, k, axis, order = atom
        if order == 0:
            return U[k]
        if atom not in cache:
            cache[atom] = _on_mode(U[k], self.s.D1[axis] if order == 1 else self.D2[axis], axis)
        return cache[atom]

    def _cross(self, s: int, terms, U: list, atoms: dict, t: float, delta: float) -> TT:
        """The monomials of species ``s`` holding functions of the unknowns, by TT-cross on the interior grid."""
        system = self.s
        points = {}
        coefficients = [np.broadcast_to(system.coefficient(s, term, t), system.shape) for term in terms]
        nodes = [z[1:-1] if k < system.space else z for k, z in enumerate(system.nodes)]

        def entries(key):
            if key not in points:
                points[key] = tt_point_function(U[key] if isinstance(key, int) else self._atom(atoms, U, key))
            return points[key]

        def values(indices: np.ndarray) -> np.ndarray:
            full_index = indices + np.array([1] * system.space + [0] * (indices.shape[1] - system.space))
            named = {m: nodes[k][indices[:, k]] for k, m in enumerate(system.modes)}
            named[system.time] = t
            named.update({sp.name: entries(k)(full_index) for k, sp in enumerate(system.species)})
            total = np.zeros(len(indices))
            for term, coef in zip(terms, coefficients):
                product = coef[tuple(full_index.T)]
                for atom in term.atoms:
                    product = product * (evaluate_tree(atom[1], named) if atom[0] == "g"
                                         else entries(atom if atom[3] else atom[1])(full_index))
                total = total + product
            return total

        shape = system.interior_shape
        result = tt_cross(values, shape, 0.5 * delta / np.sqrt(float(np.prod(shape))), max_rank=CROSS_MAX_RANK,
                          right_sets=self.right_sets.get(s), rng=np.random.default_rng(11))
        if result.right_sets:
            self.right_sets[s] = result.right_sets
        return result.train

    # -- the diffusion ----------------------------------------------------------------------------
    def phi(self, h: float) -> dict:
        return cached_coefficients(self.cache, self.spectra, h)

    def apply(self, F: list, w: list, delta: float = 0.0) -> list:
        """A phi-function per species on the merged first ``K`` modes, split again within ``delta``."""
        out = []
        for s, sp in enumerate(self.s.species):
            cores = list(w[s].cores)
            head = cores[0]
            for core in cores[1:self.K]:
                head = np.tensordot(head, core, axes=(-1, 0))
            X = head[0]  # (n_1, ..., n_K, r_K)
            for a, eig in enumerate(sp.eigen):
                X = mode_product(eig.Vinv, X, a)
            X = X * F[s][..., None]
            for a, eig in enumerate(sp.eigen):
                X = mode_product(eig.V, X, a)
            out.append(TT(_split(X, self.K, self.share * delta / np.sqrt(self.q)) + cores[self.K:]))
        return out


def _split(X: np.ndarray, K: int, delta: float) -> list:
    """Cores of the ``K`` modes of ``X`` (n_1, ..., n_K, r) by successive truncated SVDs within ``delta``."""
    X = X[None]  # (1, n_1, ..., n_K, r)
    cores = []
    step = delta / np.sqrt(max(K - 1, 1))
    for _ in range(K - 1):
        left, n = X.shape[0], X.shape[1]
        u, sv, vt = thin_svd(X.reshape(left * n, -1))
        rank = max(1, truncation_rank(sv, step))
        cores.append(u[:, :rank].reshape(left, n, rank))
        X = (sv[:rank, None] * vt[:rank]).reshape((rank,) + X.shape[2:])
    cores.append(X)
    return cores
