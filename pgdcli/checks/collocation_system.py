"""The method-of-lines system of a problem at a sample of parameter points: the operator of
:class:`~pgdcli.checks.collocation.PdeModel` assembled per sample (block-diagonal over the
samples) and per time, as the right-hand side and Jacobian that scipy's ``solve_ivp`` integrates.
Shares nothing with the PGD solver's discretization.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu, spsolve

from .collocation import PdeModel
from .reference_base import count_evaluation

__all__ = ["PdeSystem"]


class PdeSystem:
    """``y' = -(M(t)^-1) (A(t) y + b(t))`` for a chunk of samples, block-diagonal over samples."""

    def __init__(self, model: PdeModel, params: Mapping[str, np.ndarray], S: int, max_evaluations: int) -> None:
        self.model = model
        self.S = S
        self.max_evaluations = max_evaluations
        self.evaluations = 0
        self.last_y = None
        self.params = params
        self.h = model.boundary_lift(params, S)  # (S, q n)
        mass, ops, src = self._assemble(model, params, S)
        self.mass_solve = None  # M^-1 applied to the timed sources when the operators are premultiplied
        self.bad = np.zeros(S, dtype=bool)
        self.bad_reason = ""
        self.keys = sorted(set(ops) | set(src), key=lambda k: (k is not None, repr(k)))
        self.funcs = model.time_funcs
        zero = sp.csr_matrix((S * model.m, S * model.m))
        self.A = {k: sp.block_diag(ops[k], format="csr") if k in ops else zero for k in self.keys}
        self.b = {k: np.asarray(src[k]) if k in src else np.zeros(S * model.m) for k in self.keys}
        self.M = {k: sp.block_diag(mass[k], format="csr") for k in mass}
        self.static = model.static_mass
        if model.time is None:  # steady: no der(), nothing to invert
            self.diagonal = self.constant = True
            return
        self.diagonal = all((M - sp.diags(M.diagonal())).count_nonzero() == 0 for M in self.M.values())
        if self.static:
            self._mass_check(self.M.get(None, zero))
            if self.bad.any():
                return
            self._premultiply_by_mass(self.M.get(None, zero))
        self.constant = self.static and self.keys in ([], [None]) and not self.timed_joints and not self.timed_ops

    def _assemble(self, model: PdeModel, params: Mapping[str, np.ndarray], S: int) -> tuple[dict, dict, dict]:
        """Per time key, the samples' mass blocks, operator blocks and source vectors ``(mass, ops, src)``;
        sets ``timed_joints`` and ``timed_ops`` (the non-separable terms evaluated at every time)."""
        h = self.h
        mass: dict = {}
        ops: dict = {}
        src: dict = {}
        for kind, key, _, pf, coef, AZ, A in model.ops:
            w = model.weights(pf, coef, params, S)
            target = mass if kind == "mass" else ops
            target[key] = [w[i] * AZ if j is None else j + w[i] * AZ for i, j in enumerate(target.get(key, [None] * S))]
            if kind == "op":  # the known boundary part h of the state (constant in time: no mass term)
                src[key] = src.get(key, 0.0) + np.concatenate([w[i] * (A @ h[i]) for i in range(S)])
        for key, _, pf, coef, vec in model.sources:
            w = model.weights(pf, coef, params, S)
            src[key] = src.get(key, 0.0) + np.concatenate([w[i] * vec for i in range(S)])
        self.timed_joints = [(r, j) for r, j in model.joint_sources if model.time in j.coordinates]
        fixed = [(r, j) for r, j in model.joint_sources if model.time not in j.coordinates]
        if fixed:
            src[None] = src.get(None, 0.0) + model.joint_source(fixed, params, S, None)
        self.timed_ops = [(e, *self._factors(e, h)) for e in model.joint_ops if model.time in e[3].coordinates]
        fixed = [e for e in model.joint_ops if model.time not in e[3].coordinates]
        if fixed:  # constant in time: with the other operators, once
            A = model.joint_operators(fixed, params, S, None)
            ops[None] = [a @ model.Z if j is None else j + a @ model.Z for a, j in zip(A, ops.get(None, [None] * S))]
            src[None] = src.get(None, 0.0) + np.concatenate([a @ h[i] for i, a in enumerate(A)])
        return mass, ops, src

    def _premultiply_by_mass(self, M) -> None:
        """A constant mass matrix applied once: ``M^-1 A`` and ``M^-1 b`` (diagonal: a scaling)."""
        if self.diagonal:
            inv = sp.diags(1.0 / M.diagonal())
            self.A = {k: (inv @ A).tocsr() for k, A in self.A.items()}
            self.b = {k: inv @ b for k, b in self.b.items()}
            self.mass_solve = inv.__matmul__
            return
        lu = splu(M.tocsc())
        self.A = {k: sp.csr_matrix(lu.solve(A.toarray())) for k, A in self.A.items()}
        self.b = {k: lu.solve(b) for k, b in self.b.items()}
        self.mass_solve = lu.solve

    def _mass_check(self, M) -> None:
        m, S = self.model.m, self.S
        if self.diagonal:
            d = M.diagonal().reshape(S, m)
            bad = ~np.isfinite(d).all(axis=1) | (d == 0).any(axis=1)
            reason = "a coefficient of der() vanishes or is not finite at this point"
        else:
            bad = np.zeros(S, dtype=bool)
            dense = M.toarray()
            for i in range(S):
                block = dense[i * m:(i + 1) * m, i * m:(i + 1) * m]
                bad[i] = not (np.isfinite(block).all() and np.linalg.cond(block) < 1e14)
            reason = "the matrix of der() coefficients is singular at this point (not an ODE system there)"
        self.bad, self.bad_reason = bad, reason

    def _weight(self, key, t: float) -> float:
        return 1.0 if key is None else float(self.funcs[key](t))

    def matrix(self, t: float):
        A = sp.csr_matrix((self.S * self.model.m,) * 2)
        for k in self.keys:
            A = A + (self.A[k] if k is None else self._weight(k, t) * self.A[k])
        for (_, _, _, joint), left, right, _ in self.timed_ops:
            c = self.model.joint_values(joint, self.params, self.S, t).reshape(-1)
            part = left @ sp.diags(c) @ right
            A = A + (part if self.mass_solve is None else sp.csr_matrix(self.mass_solve(part.toarray())))
        return A

    def _factors(self, entry, h: np.ndarray):
        """``R (c L) Z = left diag(c) right`` over all samples (block-diagonal), and ``L h`` of the unknown: (S n,)."""
        model = self.model
        r, s, L, _ = entry
        n, S = model.grid.n, self.S
        select = sp.kron(sp.csr_matrix(([1.0], ([r], [0])), shape=(model.q, 1)), sp.identity(n), format="csr")
        left = select[model.rows]  # (m, n): the equation rows kept from the block of equation r
        right = model.Z[s * n:(s + 1) * n]  # (n, m)
        block = h[:, s * n:(s + 1) * n]
        if L is not None:
            right = L @ right
            block = (L @ block.T).T
        return (sp.block_diag([left] * S, format="csr"), sp.block_diag([right] * S, format="csr"),
                np.asarray(block).reshape(-1))

    def _mass_at(self, t: float):
        M = None
        for k, Mk in self.M.items():
            term = Mk if k is None else self._weight(k, t) * Mk
            M = term if M is None else M + term
        return M

    @property
    def invariant_operator(self) -> bool:
        """The operator is constant in time (a static mass, no time factor on any operator, no
        non-separable term of time and an unknown); the sources may depend on time."""
        return bool(self.static and not self.timed_ops
                    and all(self.A[k].count_nonzero() == 0 for k in self.keys if k is not None))

    def forcing(self, t: float) -> np.ndarray:
        """``b(t)`` of ``y' = -(A y + b(t))`` when :attr:`invariant_operator`: shape (S m,)."""
        out = np.zeros(self.S * self.model.m)
        for k in self.keys:
            out += self._weight(k, t) * self.b[k]
        if self.timed_joints:
            b = self.model.joint_source(self.timed_joints, self.params, self.S, t)
            out += b if self.mass_solve is None else self.mass_solve(b)
        return out

    def __call__(self, t: float, y: np.ndarray) -> np.ndarray:
        count_evaluation(self, y)
        out = np.zeros_like(y, dtype=float)
        for k in self.keys:
            w = self._weight(k, t)
            if w != 0.0:
                b = self.b[k] if y.ndim == 1 else self.b[k][:, None]
                out -= w * (self.A[k] @ y + b)
        if self.timed_joints:
            b = self.model.joint_source(self.timed_joints, self.params, self.S, t)
            if self.mass_solve is not None:
                b = self.mass_solve(b)
            out -= b if y.ndim == 1 else b[:, None]
        for (_, _, _, joint), left, right, hs in self.timed_ops:  # R (c L) (Z y + h), c from its tree at t
            c = self.model.joint_values(joint, self.params, self.S, t).reshape(-1)
            part = left @ (c[:, None] * (right @ y) if y.ndim == 2 else c * (right @ y)) + \
                (left @ (c * hs) if y.ndim == 1 else (left @ (c * hs))[:, None])
            out -= part if self.mass_solve is None else self.mass_solve(part)
        if self.static:
            return out
        M = self._mass_at(t)
        if self.diagonal:
            d = M.diagonal()
            return out / (d if y.ndim == 1 else d[:, None])
        return spsolve(M.tocsc(), out)

    def jacobian(self, t: float, y: np.ndarray):
        J = -self.matrix(t)
        if self.static:
            return J
        M = self._mass_at(t)
        if self.diagonal:
            return sp.diags(1.0 / M.diagonal()) @ J
        return sp.csr_matrix(splu(M.tocsc()).solve(J.toarray()))
