"""Nonlinear PDEs in one space coordinate: a tensor-train march with exact diffusion.

Building block for issue 14 item 4 (Fisher-KPP, viscous Burgers): **not yet wired into
``pgd solve``** (the driver still refuses nonlinear PDEs; the automatic resolution and the
error gate do not use it). The state ``u(t; x, p)`` is a tensor train whose first mode is the
space coordinate ``x`` (Chebyshev-Lobatto nodes of the codebook's basis) and whose other
modes are the parameters in spec order. The equation

    der(u) = c(p_k) der(u, x, 2) + N(u)

is split: the diffusion ``c(p_k) Dxx`` (one monomial, coefficient a constant or a function of
the coordinate ``p_k`` right after ``x`` in the train) is integrated exactly, per node of
``p_k``: ``exp(h c_j A)`` (``A`` the collocated ``d^2/dx^2`` on the interior nodes after the
boundary elimination) acts on the merged ``(x, p_k)`` supercore, re-split by truncated SVD. Every
other monomial (``r*u*(1 - u)``, ``-u*der(u, x)``) is ``N(u)``, evaluated explicitly with
Hadamard products and ``D`` on the ``x`` core, by the integrating-factor (Lawson) Runge-Kutta
scheme of order 4 with step-doubling error control (so the steps follow the nonlinear dynamics,
not the ``dx^2 / c`` of an explicit diffusion step; an advection ``u der(u, x)`` on Chebyshev
nodes still bounds them by ~1 / (|u| n^2)).

Boundary conditions: value or gradient with constant data at each end, lifted by the linear
``l(x) = a + b x`` that satisfies them (``D^2 l = 0``: the diffusion of the lift vanishes), the
rest ``w = u - l`` homogeneous and eliminated on the boundary nodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..discretization.basis import make_basis
from ..errors import SolverError
from ..problem.general import is_general
from ..tensors.tt import TT, tt_hadamard, tt_rank_one, tt_round, tt_sum

__all__ = ["PdeSystem", "compile_pde_system", "march_pde", "PdeMarchResult"]

SAFETY = 0.8


@dataclass
class PdeSystem:
    """The split system on the nodes.

    Attributes
    ----------
    modes : list of str
        ``[x, params...]``: the train's modes.
    nodes : list of ndarray
        Their nodes.
    A : ndarray (m, m)
        ``d^2/dx^2`` on the ``m = n - 2`` interior nodes, boundary values eliminated.
    Z : ndarray (n, m)
        Full nodal values of ``w`` from its interior values.
    lift : ndarray (n,)
        ``l`` at the nodes.
    diffusion : ndarray (n_k,) or (1,)
        ``c`` at the nodes of the diffusion parameter (mode 1), or one constant.
    terms : list of (float, list of ndarray per mode, tuple of int)
        ``N(u)``: weight, node vectors of the coefficient per mode, derivative order of each atom.
    initial : TT
        ``w(t0)`` over the interior nodes.
    """

    modes: list
    nodes: list
    A: np.ndarray
    Z: np.ndarray
    D1: np.ndarray
    lift: np.ndarray
    diffusion: np.ndarray
    terms: list
    initial: TT
    t_span: tuple


def _refuse(problem, what: str):
    raise SolverError(f"{problem.source}: equations: {what} (the PDE march takes one unknown, one space coordinate, "
                      "der(u) = c*der(u, x, 2) + polynomial terms in u and der(u, x))")


def _vectors(problem, sep, modes, nodes):
    """(weight, per-mode node vectors) of each term of a separable coefficient without time or joints."""
    if sep.joints:
        _refuse(problem, "a non-separable coefficient")
    out = []
    for term in sep.terms:
        factors = dict(term.factors)
        if problem.time in factors:
            _refuse(problem, "a time-dependent coefficient")
        vecs = [np.broadcast_to(np.asarray(factors[m](z), float), z.shape).copy() if m in factors
                else np.ones(z.size) for m, z in zip(modes, nodes)]
        out.append((float(term.coef), vecs))
    return out


def _elimination(problem, unknown, x_name: str, D1: np.ndarray):
    """Lift values (n,) and the map Z (n, n-2) of homogeneous boundary conditions."""
    n = D1.shape[0]
    ends = unknown.boundary.get(x_name)
    if ends is None:
        _refuse(problem, f"unknown {unknown.name!r} has no boundary conditions in {x_name}")
    C, g = np.zeros((2, n)), np.zeros(2)
    for side, bc in enumerate(ends):
        node = 0 if side == 0 else n - 1
        C[side] = np.eye(n)[node] if bc.kind == "value" else D1[node]
        value = 0.0 if bc.value.is_zero else bc.value.constant_value
        if value is None:
            _refuse(problem, "boundary values depending on coordinates")
        g[side] = value
    B, interior = np.array([0, n - 1]), np.arange(1, n - 1)
    Z = np.zeros((n, n - 2))
    Z[interior, np.arange(n - 2)] = 1.0
    Z[B] = -np.linalg.solve(C[:, B], C[:, interior])
    return C, g, Z


def compile_pde_system(problem, nodes: dict) -> PdeSystem:
    """The split system of ``problem`` on ``nodes`` (coordinate -> node count, time excluded)."""
    space = [c for c in problem.coordinates if c.role == "space"]
    if len(space) != 1 or len(problem.unknowns) != 1:
        _refuse(problem, "several space coordinates or unknowns")
    x = space[0]
    coords = [c for c in problem.coordinates if c.name != problem.time]
    if coords[0].name != x.name:
        _refuse(problem, f"{x.name} must be the first coordinate after time")
    bases = [make_basis("chebyshev", c.domain, nodes[c.name]) for c in coords]
    modes, grid = [c.name for c in coords], [b.nodes for b in bases]
    D1 = bases[0].derivative
    unknown = problem.unknowns[0]
    C, g, Z = _elimination(problem, unknown, x.name, D1)
    xs = grid[0]
    # lift l = a + b (x - x0): two conditions, two unknowns
    basis = np.stack([np.ones_like(xs), xs - xs[0]], axis=1)  # (n, 2)
    a_b = np.linalg.solve(C @ basis, g)
    lift = basis @ a_b
    A = (D1 @ D1 @ Z)[1:-1]
    diffusion, terms, mass = None, [], None
    for monomial, sep in problem.equations[0].polynomial.items():
        orders = tuple(a.order if a.coordinate != problem.time else -1 for a in monomial)
        if any(is_general(a) for a in monomial):
            _refuse(problem, "a function of the unknown")
        if orders == (-1,):
            mass = _vectors(problem, sep, modes, grid)
            continue
        if -1 in orders or any(o > 2 for o in orders):
            _refuse(problem, "der(u) must appear alone")
        vecs = _vectors(problem, sep, modes, grid)
        if orders == (2,) and diffusion is None and len(vecs) == 1 and all(
                np.all(v == v[0]) for i, v in enumerate(vecs[0][1]) if i != 1):
            weight, vs = vecs[0]
            diffusion = -weight * np.prod([v[0] for i, v in enumerate(vs) if i != 1]) * vs[1] if len(vs) > 1 \
                else np.array([-weight])
            continue
        terms += [(w, v, orders) for w, v in vecs]
    if mass is None or len(mass) != 1 or any(np.any(v != 1.0) for v in mass[0][1]) or mass[0][0] == 0:
        _refuse(problem, "the coefficient of der(u) must be a constant")
    scale = 1.0 / mass[0][0]
    if diffusion is None:
        _refuse(problem, "no diffusion term c*der(u, x, 2) with c constant or a function of the coordinate after x")
    terms = [(-w * scale, v, o) for w, v, o in terms]
    diffusion = diffusion * scale
    mesh = np.meshgrid(*grid, indexing="ij")
    u0 = np.broadcast_to(unknown.initial.evaluate(**{m: v for m, v in zip(modes, mesh)}), mesh[0].shape)
    w0 = (u0 - lift.reshape((-1,) + (1,) * (len(modes) - 1)))[1:-1]
    initial = _tt_from_full(w0, 1e-13 * float(np.linalg.norm(w0)))
    t = problem.time_coordinate.domain
    return PdeSystem(modes, grid, A, Z, D1, lift, diffusion, terms, initial, (float(t[0]), float(t[1])))


def _tt_from_full(full: np.ndarray, delta: float) -> TT:
    """TT-SVD of a full tensor to the Frobenius error ``delta``."""
    shape = full.shape
    cores, r, rest = [], 1, full.reshape(1, -1)
    d = len(shape)
    for k in range(d - 1):
        mat = rest.reshape(r * shape[k], -1)
        u, s, vt = np.linalg.svd(mat, full_matrices=False)
        tail = np.sqrt(np.cumsum((s * s)[::-1]))[::-1]
        rank = max(1, int(np.sum(tail > delta / np.sqrt(max(d - 1, 1)))))
        cores.append(u[:, :rank].reshape(r, shape[k], rank))
        rest = s[:rank, None] * vt[:rank]
        r = rank
    cores.append(rest.reshape(r, shape[-1], 1))
    return TT(cores)


@dataclass
class PdeMarchResult:
    """States ``u`` (full ``x`` nodes) at the output times, and the march's counts."""

    times: np.ndarray
    states: list
    steps: int
    rejected: int
    max_rank: int


def _on_x(train: TT, M: np.ndarray) -> TT:
    """``M`` applied to the ``x`` mode (the first core)."""
    cores = list(train.cores)
    cores[0] = np.einsum("ij,ajb->aib", M, cores[0])
    return TT(cores)


def _scaled_modes(train: TT, vectors) -> TT:
    """Hadamard product with a rank-one train given by node vectors per mode."""
    return TT([c * v[None, :, None] for c, v in zip(train.cores, vectors)])


class _Split:
    """The two parts of the split system on tensor trains, with the exponential cache."""

    def __init__(self, system: PdeSystem, tolerance: float) -> None:
        self.s = system
        self.size = float(np.prod([z.size for z in system.nodes]))
        self.ones = [np.ones(z.size) for z in system.nodes[1:]]
        self.lift = tt_rank_one([system.lift] + self.ones)
        self.tolerance = tolerance
        self.cache: dict = {}

    def full(self, w: TT) -> TT:
        return tt_sum([_on_x(w, self.s.Z), self.lift], [1.0, 1.0])

    def nonlinear(self, w: TT, delta: float) -> TT:
        """``N(u)`` on the interior nodes, rounded to the Frobenius ``delta``."""
        u = self.full(w)
        atoms = {0: u, 1: _on_x(u, self.s.D1), 2: _on_x(u, self.s.D1 @ self.s.D1)}
        parts = []
        for weight, vectors, orders in self.s.terms:
            product = None
            for o in orders:
                atom = atoms[o]
                product = atom if product is None else tt_round(tt_hadamard(product, atom), absolute=0.1 * delta)
            product = tt_rank_one(vectors) if product is None else _scaled_modes(product, vectors)
            parts.append(product.scaled(weight))
        total = tt_round(tt_sum(parts), absolute=delta)
        cores = list(total.cores)
        cores[0] = cores[0][:, 1:-1, :]
        return TT(cores)

    def _exponentials(self, h: float) -> np.ndarray:
        key = float(h)
        if key not in self.cache:
            if len(self.cache) > 16:
                self.cache.clear()
            self.cache[key] = np.stack([sla.expm(h * c * self.s.A) for c in self.s.diffusion])
        return self.cache[key]

    def exp(self, h: float, w: TT, delta: float) -> TT:
        """``exp(h c(p) A) w``: exact on the x core, or per node of mode 1 on the merged supercore."""
        E = self._exponentials(h)
        if E.shape[0] == 1:
            return _on_x(w, E[0])
        cores = list(w.cores)
        W = np.einsum("aib,bjc->ijc", cores[0], cores[1])  # (m, n_k, r2)
        W = np.einsum("jil,ljc->ijc", E, W)
        m, nk, r2 = W.shape
        u, sv, vt = np.linalg.svd(W.reshape(m, nk * r2), full_matrices=False)
        tail = np.sqrt(np.cumsum((sv * sv)[::-1]))[::-1]
        rank = max(1, int(np.sum(tail > delta)))
        cores[0] = u[:, :rank].reshape(1, m, rank)
        cores[1] = (sv[:rank, None] * vt[:rank]).reshape(rank, nk, r2)
        return TT(cores)


def _lawson4(split: _Split, w: TT, h: float, delta: float) -> TT:
    """One integrating-factor (Lawson) RK4 step of ``w' = c A w + N(w)``."""
    E = split.exp

    def add(x, y, b):
        return tt_round(tt_sum([x, y], [1.0, b]), absolute=delta)

    k1 = split.nonlinear(w, delta / h)
    half_w = E(h / 2, w, delta)
    k2 = split.nonlinear(add(half_w, E(h / 2, k1, delta), h / 2), delta / h)
    k3 = split.nonlinear(add(half_w, k2, h / 2), delta / h)
    full_w = E(h / 2, half_w, delta)
    k4 = split.nonlinear(add(full_w, E(h / 2, k3, delta), h), delta / h)
    combo = tt_sum([E(h, k1, delta), E(h / 2, tt_sum([k2, k3]), delta), k4], [1.0, 2.0, 1.0])
    return tt_round(tt_sum([full_w, combo], [1.0, h / 6]), absolute=delta)


def march_pde(system: PdeSystem, tolerance: float, times: np.ndarray, *, max_steps: int = 20000) -> PdeMarchResult:
    """March ``w`` with Lawson RK4 and step doubling; states ``u`` at ``times`` (ascending, in the span).

    The local error (step doubling, Richardson: ``(half - whole) / 15``) is held in the RMS over the
    grid to ``0.3 tolerance h / T`` per step; every rounding to ``0.02 tolerance h / T`` (Frobenius
    bound scaled by ``sqrt(grid size)``).
    """
    from threadpoolctl import threadpool_limits

    # small dense products (QR, expm of n x n): one BLAS thread. Measured on fisher.yaml (x 33, D 9, r 9) on the
    # shared 2-core machine: 15 step attempts in 47 s with the default threads, 1086 steps in 33 s with one
    with threadpool_limits(1):
        return _march(system, tolerance, times, max_steps)


def _march(system: PdeSystem, tolerance: float, times: np.ndarray, max_steps: int) -> PdeMarchResult:
    split = _Split(system, tolerance)
    t0, t1 = system.t_span
    T = t1 - t0
    root = np.sqrt(split.size)
    w, t, h = system.initial, t0, 1e-3 * T
    out_times = np.asarray(times, dtype=float)
    states, steps, rejected, max_rank = [], 0, 0, 1
    for target in out_times:
        while t < target - 1e-14 * T:
            if steps + rejected > max_steps:
                raise SolverError(f"the PDE march took more than {max_steps} steps at t = {t:.6g}")
            h = min(h, target - t)
            delta = 0.02 * tolerance * h / T * root
            whole = _lawson4(split, w, h, delta)
            half = _lawson4(split, _lawson4(split, w, h / 2, delta), h / 2, delta)
            diff = tt_sum([half, whole], [1.0, -1.0])
            err = diff.norm() / 15.0 / root
            allowed = 0.3 * tolerance * h / T
            if err <= allowed:
                w = tt_round(tt_sum([half, diff], [1.0, 1.0 / 15.0]), absolute=delta)
                t += h
                steps += 1
                max_rank = max(max_rank, max(w.ranks))
            else:
                rejected += 1
            h *= min(2.0, max(0.2, SAFETY * (allowed / max(err, 1e-300)) ** 0.2))
        states.append(split.full(w))
    return PdeMarchResult(out_times, states, steps, rejected, max_rank)
