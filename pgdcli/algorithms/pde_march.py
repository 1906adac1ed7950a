"""Nonlinear PDEs in one space coordinate: an exponential tensor-train march.

The system (:mod:`.pde_system`) is ``w' = c(p_k) A w + N(w)`` on a tensor train over ``(x, p_k,
other parameters)``. The diffusion is integrated exactly, per node of ``p_k``: a matrix function of
``h c_j A`` acts on the merged ``(x, p_k)`` supercore, re-split by truncated SVD (or on the ``x`` core
alone when ``c`` is a constant). ``N(w)`` is explicit (Hadamard products, ``D`` on the ``x`` core).

Two schemes:

* ``etdrk4`` (default): the exponential time differencing Runge-Kutta scheme of order 4 of Cox &
  Matthews (2002), its coefficients ``phi_k(h c_j A)`` from :mod:`.pde_phi` (contour integral of
  Kassam & Trefethen on one eigendecomposition). Its error constant involves derivatives of
  ``N`` along the solution only, so the diffusion's stiffness does not shrink its steps.
* ``lawson4``: the integrating-factor (Lawson) Runge-Kutta scheme of order 4, kept for the
  comparison (``benchmarks/nonlinear_pde.py``): its error constant holds commutators of ``A`` with
  ``N``, large for stiff diffusion (Fisher: 1077 steps against ETDRK4's ~60).

Both with step doubling (Richardson: ``(half - whole) / 15``, the accepted state extrapolated),
the local error held in the RMS over the grid to ``LOCAL_FRACTION * tolerance * h / T`` per step,
every rounding to ``ROUND_FRACTION * tolerance * h / T``. An advection ``u der(u, x)`` stays explicit:
on Chebyshev nodes it bounds the steps by ~ 1 / (|u| n^2).

Output: the states ``u`` (full ``x`` nodes) at given times, or (``slab_nodes``) one slab per accepted
step with the states at its Chebyshev-Lobatto nodes, the inner ones by single steps of their size
from the start of the step (sharing its first ``N`` evaluation).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..blas import one_blas_thread
from ..discretization.basis import chebyshev_unit_nodes
from ..errors import SolverError
from ..tensors.cross import tt_from_full
from ..tensors.tt import TT, tt_hadamard, tt_rank_one, tt_round, tt_sum
from .pde_phi import Eigen
from .pde_system import PdeSystem, compile_pde_system

__all__ = ["PdeSystem", "compile_pde_system", "march_pde", "PdeMarchResult", "SCHEMES", "UnderResolved"]

SAFETY = 0.8
LOCAL_FRACTION, ROUND_FRACTION = 0.3, 0.02
#: A step below this share of the time span ends the march.
MIN_STEP = 1e-9
SCHEMES = ("etdrk4", "lawson4")
#: Largest grid (values) marched as a whole array instead of a tensor train.
DENSE_LIMIT = 200_000
#: With ``tail_limit``, the march stops once the Chebyshev tail of ``u`` along ``x`` exceeds this many times
#: the tolerance: the codebook would fail the gate there anyway (its tail alone), and an under-resolved
#: steep front (Burgers at nu = 0.01 on 33 nodes) oscillates, which an explicit advection answers with
#: ever smaller steps (924 steps to t = 0.35, still shrinking, against 92 steps to t = 0.5 on 129 nodes).
TAIL_ABORT = 10.0


class UnderResolved(SolverError):
    """The march stopped: ``x`` lacks nodes (its Chebyshev tail, ``tail``, at ``time``)."""

    def __init__(self, message: str, coordinate: str, time: float, tail: float) -> None:
        super().__init__(message)
        self.coordinate, self.time, self.tail = coordinate, time, tail


def _tail_rows(n: int) -> np.ndarray:
    """Rows mapping values at the n Chebyshev-Lobatto nodes (ascending) to the last two coefficients."""
    x = -np.cos(np.pi * np.arange(n) / (n - 1))
    return np.linalg.inv(np.polynomial.chebyshev.chebvander(x, n - 1))[-2:]


@dataclass
class PdeMarchResult:
    """States ``u`` (TT over the full ``x`` nodes and the parameters) at ``times``, and the march's counts."""

    times: np.ndarray
    states: list
    steps: int
    rejected: int
    max_rank: int
    breakpoints: np.ndarray | None = None
    step_sizes: list = field(default_factory=list)
    evaluations: int = 0


def _on_x(train: TT, M: np.ndarray) -> TT:
    """``M`` applied to the ``x`` mode (the first core)."""
    cores = list(train.cores)
    cores[0] = np.einsum("ij,ajb->aib", M, cores[0])
    return TT(cores)


def _scaled_modes(train: TT, vectors) -> TT:
    """Hadamard product with a rank-one train given by node vectors per mode."""
    return TT([c * v[None, :, None] for c, v in zip(train.cores, vectors)])


class _Split:
    """The two parts of the split system on tensor trains, with the matrix-function cache."""

    def __init__(self, system: PdeSystem) -> None:
        self.s = system
        self.size = float(np.prod(system.shape))
        self.lift = tt_rank_one([system.lift] + [np.ones(z.size) for z in system.nodes[1:]])
        self.D2 = system.D1 @ system.D1
        self.eigen = Eigen(system.A)
        self.cache: dict = {}
        self.evaluations = 0

    def full(self, w: TT) -> TT:
        return tt_sum([_on_x(w, self.s.Z), self.lift], [1.0, 1.0])

    @staticmethod
    def combine(terms, weights, delta: float) -> TT:
        """The weighted sum, rounded to the Frobenius ``delta`` (0: exact, ranks added)."""
        total = tt_sum(terms, weights)
        return tt_round(total, absolute=delta) if delta > 0 else total

    @staticmethod
    def norm(w: TT) -> float:
        return w.norm()

    @staticmethod
    def rank(w: TT) -> int:
        return max(w.ranks, default=1)

    def tail(self, w: TT) -> float:
        return 0.0  # not watched on trains (grids above DENSE_LIMIT): the gate measures the codebook's

    def state(self, w: TT, delta: float) -> TT:
        """``u`` of the interior state ``w`` as a train over the full nodes."""
        return self.full(w)

    def nonlinear(self, w: TT, delta: float) -> TT:
        """``N(u)`` on the interior nodes, rounded to the Frobenius ``delta``."""
        self.evaluations += 1
        u = self.full(w)
        atoms = {0: u}
        parts = []
        for weight, vectors, orders in self.s.terms:
            product = None
            for o in orders:
                if o not in atoms:
                    atoms[o] = _on_x(u, self.s.D1 if o == 1 else self.D2)
                product = atoms[o] if product is None else tt_round(tt_hadamard(product, atoms[o]),
                                                                    absolute=0.1 * delta)
            product = tt_rank_one(vectors) if product is None else _scaled_modes(product, vectors)
            parts.append(product.scaled(weight))
        if not parts:
            return TT([np.zeros((1, n - 2 if k == 0 else n, 1)) for k, n in enumerate(self.s.shape)])
        total = tt_round(tt_sum(parts), absolute=delta)
        cores = list(total.cores)
        cores[0] = cores[0][:, 1:-1, :]
        return TT(cores)

    def functions(self, h: float) -> np.ndarray:
        """``phi_0 .. phi_3`` of ``h c_j A`` and of ``h c_j A / 2``: shape (2, 4, n_k, m) as spectra in the
        eigenbasis of ``A`` (or (2, 4, n_k, m, m) as matrices when its eigenvectors are ill-conditioned)."""
        key = float(h)
        if key not in self.cache:
            if len(self.cache) > 8:
                self.cache.clear()
            c = np.asarray(self.s.diffusion, dtype=float)
            scales = np.concatenate([h * c, 0.5 * h * c])
            both = self.eigen.spectra(scales, 3)
            if both is None:
                both = self.eigen.functions(scales, 3)  # (4, 2 n_k, m, m)
            self.cache[key] = np.stack([both[:, :c.size], both[:, c.size:]])
        return self.cache[key]

    def apply(self, M: np.ndarray, w: TT, delta: float) -> TT:
        """A function of ``c_j A`` applied per node j of mode 1 (or of ``c A`` on the ``x`` core), rounded to
        ``delta``. ``M``: spectra (n_k, m) or matrices (n_k, m, m)."""
        cores = list(w.cores)
        if M.shape[0] == 1:
            core = np.transpose(cores[0], (1, 0, 2))  # (m, 1, r)
            core = self.eigen.apply(M, core) if M.ndim == 2 else np.einsum("ij,jab->iab", M[0], core)
            cores[0] = np.transpose(core, (1, 0, 2))
            return TT(cores)
        W = np.einsum("aib,bjc->ijc", cores[0], cores[1])  # (m, n_k, r2)
        W = self.eigen.apply(M, W) if M.ndim == 2 else np.einsum("jil,ljc->ijc", M, W)
        m, nk, r2 = W.shape
        u, sv, vt = np.linalg.svd(W.reshape(m, nk * r2), full_matrices=False)
        tail = np.sqrt(np.cumsum((sv * sv)[::-1]))[::-1]
        rank = max(1, int(np.sum(tail > delta)))
        cores[0] = u[:, :rank].reshape(1, m, rank)
        cores[1] = (sv[:rank, None] * vt[:rank]).reshape(rank, nk, r2)
        return TT(cores)


class _Dense(_Split):
    """The same operations on the whole grid (numpy arrays (m, n_2, ..., n_d)), no rounding.

    Chosen while the grid has at most :data:`DENSE_LIMIT` values: on Fisher's 65 x 17 x 17 nodes
    the whole grid is 18785 values, and the trains' QR and SVD roundings (rank ~20) took most of the
    march's time.
    """

    def __init__(self, system: PdeSystem) -> None:
        super().__init__(system)
        self.lift_full = system.lift.reshape((-1,) + (1,) * (len(system.shape) - 1))

    def initial(self):
        return self.s.initial.full()

    def full(self, w: np.ndarray) -> np.ndarray:
        return np.tensordot(self.s.Z, w, axes=(1, 0)) + self.lift_full

    @staticmethod
    def combine(terms, weights, delta: float) -> np.ndarray:
        return sum(b * t for t, b in zip(terms, weights))

    @staticmethod
    def norm(w: np.ndarray) -> float:
        return float(np.linalg.norm(w))

    @staticmethod
    def rank(w) -> int:
        return 0

    def state(self, w: np.ndarray, delta: float) -> TT:
        return tt_from_full(self.full(w), delta)

    def tail(self, w: np.ndarray) -> float:
        """RMS over the parameter nodes of the larger of the last two Chebyshev coefficients along ``x``."""
        if not hasattr(self, "_tail"):
            self._tail = _tail_rows(self.s.shape[0])
        coef = np.abs(np.tensordot(self._tail, self.full(w), axes=(1, 0))).max(axis=0)
        return float(np.sqrt(np.mean(coef * coef)))

    def nonlinear(self, w: np.ndarray, delta: float) -> np.ndarray:
        self.evaluations += 1
        u = self.full(w)
        atoms = {0: u}
        total = np.zeros_like(u)
        for weight, vectors, orders in self.s.terms:
            product = weight
            for o in orders:
                if o not in atoms:
                    atoms[o] = np.tensordot(self.s.D1 if o == 1 else self.D2, u, axes=(1, 0))
                product = product * atoms[o]
            for k, v in enumerate(vectors):
                product = product * v.reshape((1,) * k + (-1,) + (1,) * (len(vectors) - k - 1))
            total = total + product
        return total[1:-1]

    def apply(self, M: np.ndarray, w: np.ndarray, delta: float) -> np.ndarray:
        shape = w.shape
        W = w.reshape(shape[0], shape[1] if len(shape) > 1 else 1, -1)  # (m, n_k, rest)
        if M.shape[0] == 1:
            W = w.reshape(shape[0], 1, -1)
        out = self.eigen.apply(M, W) if M.ndim == 2 else np.einsum("jil,ljc->ijc", M, W)
        return out.reshape(shape)


def _etdrk4(split: _Split, w: TT, h: float, delta: float, Nw: TT | None = None) -> TT:
    """One ETDRK4 step (Cox & Matthews) of ``w' = c A w + N(w)``; ``Nw`` reuses ``N(w)``."""
    F = split.functions(h)
    full, half = F[0], F[1]
    E, E2, Q = full[0], half[0], 0.5 * h * half[1]
    # the weights of the four stages: h (phi1 - 3 phi2 + 4 phi3), h (2 phi2 - 4 phi3) twice, h (4 phi3 - phi2)
    b1 = h * (full[1] - 3 * full[2] + 4 * full[3])
    b23 = h * (2 * full[2] - 4 * full[3])
    b4 = h * (4 * full[3] - full[2])
    ap, nl, _combine = split.apply, split.nonlinear, split.combine
    Na = nl(w, delta / h) if Nw is None else Nw
    E2w = ap(E2, w, delta)
    a = _combine([E2w, ap(Q, Na, delta)], [1.0, 1.0], delta)
    Nb = nl(a, delta / h)
    b = _combine([E2w, ap(Q, Nb, delta)], [1.0, 1.0], delta)
    Nc = nl(b, delta / h)
    c = _combine([ap(E2, a, delta), ap(Q, _combine([Nc, Na], [2.0, -1.0], delta / h), delta)], [1.0, 1.0], delta)
    Nd = nl(c, delta / h)
    parts = [ap(E, w, delta), ap(b1, Na, delta), ap(b23, _combine([Nb, Nc], [1.0, 1.0], delta / h), delta),
             ap(b4, Nd, delta)]
    return _combine(parts, [1.0] * 4, delta)


def _lawson4(split: _Split, w: TT, h: float, delta: float, Nw: TT | None = None) -> TT:
    """One integrating-factor (Lawson) RK4 step of ``w' = c A w + N(w)``."""
    F = split.functions(h)
    E, E2 = F[0][0], F[1][0]
    ap, nl, _combine = split.apply, split.nonlinear, split.combine
    k1 = nl(w, delta / h) if Nw is None else Nw
    half_w = ap(E2, w, delta)
    k2 = nl(_combine([half_w, ap(E2, k1, delta)], [1.0, h / 2], delta), delta / h)
    k3 = nl(_combine([half_w, k2], [1.0, h / 2], delta), delta / h)
    full_w = ap(E2, half_w, delta)
    k4 = nl(_combine([full_w, ap(E2, k3, delta)], [1.0, h], delta), delta / h)
    combo = _combine([ap(E, k1, delta), ap(E2, _combine([k2, k3], [1.0, 1.0], 0.0), delta), k4], [1.0, 2.0, 1.0], 0.0)
    return _combine([full_w, combo], [1.0, h / 6], delta)


def march_pde(system: PdeSystem, tolerance: float, times: np.ndarray | None = None, *, scheme: str = "etdrk4",
              slab_nodes: int | None = None, max_steps: int = 20000, callback=None,
              fixed_step: float | None = None, dense: bool | None = None,
              tail_limit: bool = False) -> PdeMarchResult:
    """March ``w`` with step doubling; the states ``u`` at ``times`` or at per-step slab nodes.

    Parameters
    ----------
    system : PdeSystem
    tolerance : float
        RMS target over the grid (see the module docstring).
    times : ndarray, optional
        Ascending output times in the span (the steps land on them).
    scheme : {'etdrk4', 'lawson4'}
    slab_nodes : int, optional
        Instead of ``times``: one slab per accepted step with this many Chebyshev-Lobatto nodes.
    fixed_step : float, optional
        Steps of this size (shortened to land on the output times), every one accepted: the scheme's
        order can be measured.
    dense : bool, optional
        March the whole grid as an array (default: when it has at most :data:`DENSE_LIMIT` values) or
        as a tensor train.
    tail_limit : bool
        Stop with :class:`UnderResolved` once the Chebyshev tail of ``u`` along ``x`` exceeds
        :data:`TAIL_ABORT` x ``tolerance`` (whole-grid march only).
    """
    if scheme not in SCHEMES:
        raise SolverError(f"scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")
    # small dense products (SVD of the supercore, m x m products): one BLAS thread. Measured on fisher.yaml
    # (x 33, D 9, r 9) on the shared 2-core machine: 15 step attempts in 47 s with the default threads, 1086
    # steps in 33 s with one
    with one_blas_thread():
        return _march(system, tolerance, times, {"etdrk4": _etdrk4, "lawson4": _lawson4}[scheme], slab_nodes,
                      max_steps, callback, fixed_step, dense, tail_limit)


def _march(system, tolerance, times, step, slab_nodes, max_steps, callback, fixed_step=None,
           dense=None, tail_limit=False) -> PdeMarchResult:
    t0, t1 = system.t_span
    T = t1 - t0
    size = float(np.prod(system.shape))
    dense = size <= DENSE_LIMIT if dense is None else dense
    split = _Dense(system) if dense else _Split(system)
    root = np.sqrt(size)
    w, t, h = (split.initial() if dense else system.initial), t0, fixed_step or 1e-3 * T
    targets = np.asarray([t1] if times is None else times, dtype=float)
    theta = (chebyshev_unit_nodes(slab_nodes) + 1.0) / 2.0 if slab_nodes else None  # nodes on [0, 1]
    state_delta = ROUND_FRACTION * tolerance * root  # the stored states' rounding (dense: their TT-SVD)
    out_times, states = ([t0], [split.state(w, state_delta)]) if slab_nodes else ([], [])
    steps, rejected, max_rank, sizes = 0, 0, split.rank(w), []
    for target in targets:
        while t < target - 1e-14 * T:
            if steps + rejected > max_steps:
                raise SolverError(f"the PDE march took more than {max_steps} steps at t = {t:.6g}")
            if h < MIN_STEP * T:
                raise SolverError(f"the PDE march's step fell below {MIN_STEP:g} x the time span at t = {t:.6g} "
                                  f"(stiff explicit terms: an advection on many x nodes?)")
            h = min(h, target - t)
            delta = ROUND_FRACTION * tolerance * h / T * root
            Nw = split.nonlinear(w, delta / h)
            whole = step(split, w, h, delta, Nw)
            half = step(split, step(split, w, h / 2, delta, Nw), h / 2, delta)
            diff = split.combine([half, whole], [1.0, -1.0], 0.0)
            err = split.norm(diff) / 15.0 / root
            allowed = LOCAL_FRACTION * tolerance * h / T
            if err <= allowed or fixed_step:
                if slab_nodes:
                    for th in theta[1:-1]:
                        states.append(split.state(step(split, w, th * h, delta, Nw), state_delta))
                        out_times.append(t + th * h)
                w = split.combine([half, diff], [1.0, 1.0 / 15.0], delta)
                t += h
                steps += 1
                sizes.append(h)
                max_rank = max(max_rank, split.rank(w))
                tail = split.tail(w) if tail_limit else 0.0
                if tail > TAIL_ABORT * tolerance:
                    raise UnderResolved(f"{system.modes[0]} lacks nodes: the Chebyshev tail of u along it reached "
                                        f"{tail:.2g} ({tail / tolerance:.3g} x the tolerance) at t = {t:.6g} on "
                                        f"{system.shape[0]} nodes", system.modes[0], t, tail)
                if slab_nodes:
                    states.append(split.state(w, state_delta))
                    out_times.append(t)
                if callback is not None:
                    callback({"time": t, "end": t1, "steps": steps, "ranks": [[max_rank]]})  # per unknown
            else:
                rejected += 1
            h = fixed_step or h * min(2.0, max(0.2, SAFETY * (allowed / max(err, 1e-300)) ** 0.2))
        if not slab_nodes:
            states.append(split.state(w, state_delta))
            out_times.append(t)
    max_rank = max(max_rank, max(max(s.ranks, default=1) for s in states))
    breakpoints = np.concatenate([[t0], np.cumsum(sizes) + t0]) if slab_nodes else None
    return PdeMarchResult(np.asarray(out_times), states, steps, rejected, max_rank, breakpoints, sizes,
                          split.evaluations)
