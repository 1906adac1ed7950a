"""A nonlinear PDE in one space coordinate, split for the exponential march (:mod:`.pde_march`).

The state ``u(t; x, p)`` is a tensor train whose first mode is the space coordinate ``x``
(Chebyshev-Lobatto nodes of the codebook's basis), the second the parameter the diffusion
coefficient depends on (if any), then the other parameters in spec order. The equation

    der(u) = c(p_k) der(u, x, 2) + N(u)

is split into the diffusion ``c(p_k) A`` (``A`` the collocated ``d^2/dx^2`` on the interior nodes,
boundary values eliminated), which the march integrates exactly per node of ``p_k``, and every
other monomial ``N(u)`` (``r*u*(1 - u)``, ``-u*der(u, x)``, a separable source), evaluated
explicitly with Hadamard products and ``D`` on the ``x`` core.

Boundary conditions: value or gradient with constant data at each end, lifted by the linear
``l(x) = a + b x`` that satisfies them (``D^2 l = 0``: the diffusion of the lift vanishes), the
rest ``w = u - l`` homogeneous and eliminated on the boundary nodes.

What is refused (:class:`~pgdcli.errors.SolverError`, one line naming the term): several unknowns or
space coordinates, a time-dependent or non-separable coefficient, a function of the unknown
(``sin(u)``), a diffusion coefficient depending on ``x`` or on several parameters, boundary data
depending on coordinates, a non-Chebyshev or element-split space coordinate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SolverError
from ..problem.general import is_general
from ..tensors.cross import tt_from_full
from ..tensors.tt import TT

__all__ = ["PdeSystem", "compile_pde_system", "pde_refusal"]

#: What the PDE march integrates, for refusals.
SCOPE = ("the PDE march takes one unknown and one space coordinate: der(u) = c*der(u, x, 2) + polynomial terms "
         "in u, der(u, x), der(u, x, 2) with coefficients separable in the parameters")


@dataclass
class PdeSystem:
    """The split system on the nodes.

    Attributes
    ----------
    modes : list of str
        The train's modes: ``[x, p_k (diffusion's parameter, if any), other parameters...]``.
    nodes : list of ndarray
        Their nodes.
    A : ndarray (m, m)
        ``d^2/dx^2`` on the ``m = n - 2`` interior nodes, boundary values eliminated.
    Z : ndarray (n, m)
        Full nodal values of ``w`` from its interior values.
    D1 : ndarray (n, n)
        ``d/dx`` on the ``x`` nodes.
    lift : ndarray (n,)
        ``l`` at the nodes.
    diffusion : ndarray (n_k,) or (1,)
        ``c`` at the nodes of mode 1, or one constant.
    terms : list of (float, list of ndarray per mode, tuple of int)
        ``N(u)``: weight, node vectors of the coefficient per mode, derivative order in ``x`` of each atom.
    initial : TT
        ``w(t0)`` over the interior nodes.
    t_span : (float, float)
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

    @property
    def shape(self) -> tuple:
        return tuple(z.size for z in self.nodes)


def pde_refusal(problem) -> str | None:
    """Why the PDE march cannot take ``problem`` (one clause), or None when its form fits.

    Checks the structure only (coordinates, unknowns, terms, conditions), not the node counts.
    """
    try:
        _structure(problem)
    except SolverError as exc:
        return str(exc)
    return None


def _refuse(problem, what: str):
    raise SolverError(f"{problem.source}: equations: {what} ({SCOPE})")


def _structure(problem):
    """The space coordinate, the unknown, the diffusion's parameter (or None); refuses what does not fit."""
    space = [c for c in problem.coordinates if c.role == "space"]
    if len(space) != 1:
        _refuse(problem, f"{len(space)} space coordinates ({', '.join(c.name for c in space)})")
    rates = [u for u in problem.unknowns if u.rate_of]
    if rates:  # the user wrote one unknown: say why there are two
        _refuse(problem, f"der({rates[0].rate_of}, t, 2) makes a system of {rates[0].rate_of} and its rate "
                         f"{rates[0].name} (second-order time derivatives are not supported in nonlinear PDEs)")
    if len(problem.unknowns) != 1 or len(problem.equations) != 1:
        _refuse(problem, f"{len(problem.unknowns)} unknowns ({', '.join(u.name for u in problem.unknowns)})")
    x = space[0]
    if x.discretization != "chebyshev" or len(x.breakpoints) > 2:
        _refuse(problem, f"space coordinate {x.name!r} must be one Chebyshev element")
    unknown = problem.unknowns[0]
    ends = unknown.boundary.get(x.name)
    if ends is None:
        _refuse(problem, f"unknown {unknown.name!r} needs boundary conditions at both ends of {x.name}")
    for bc in ends:
        if bc.kind not in ("value", "gradient"):
            _refuse(problem, f"a {bc.kind} boundary condition")
        if not bc.value.is_zero and bc.value.constant_value is None:
            _refuse(problem, "boundary values that depend on coordinates")
    diffusion_param, seen_diffusion, mass = None, False, None
    for monomial, sep in problem.equations[0].polynomial.items():
        if any(is_general(a) for a in monomial):
            _refuse(problem, "a function of the unknown (sin(u), sqrt(u), ...)")
        if sep.joints:
            _refuse(problem, "a non-separable coefficient")
        for term in sep.terms:
            if problem.time in dict(term.factors):
                _refuse(problem, "a time-dependent coefficient")
        orders = _orders(problem, monomial)
        if -1 in orders:
            if orders != (-1,):
                _refuse(problem, f"der({unknown.name}) must appear alone and linearly")
            mass = sep
            continue
        if any(o > 2 for o in orders):
            _refuse(problem, "a space derivative of order above 2")
        if orders == (2,) and not seen_diffusion:
            seen_diffusion = True
            diffusion_param = _diffusion_parameter(problem, sep, x.name)
    if mass is None or len(mass.terms) != 1 or dict(mass.terms[0].factors) or mass.terms[0].coef == 0:
        _refuse(problem, f"the coefficient of der({unknown.name}) must be a nonzero constant")
    if not seen_diffusion:
        _refuse(problem, f"no diffusion term c*der({unknown.name}, {x.name}, 2)")
    return x, unknown, diffusion_param


def _orders(problem, monomial) -> tuple:
    """Derivative order in space of each atom; -1 for der(u) in time."""
    return tuple(-1 if a.coordinate == problem.time and a.order else a.order for a in monomial)


def _diffusion_parameter(problem, sep, x_name: str):
    """The one parameter the diffusion coefficient depends on (None: a constant); refuses the rest."""
    if len(sep.terms) != 1:
        _refuse(problem, "a diffusion coefficient with several terms")
    factors = dict(sep.terms[0].factors)
    if x_name in factors:
        _refuse(problem, f"a diffusion coefficient depending on {x_name}")
    if len(factors) > 1:
        _refuse(problem, "a diffusion coefficient depending on several parameters")
    return next(iter(factors), None)


def _vectors(problem, sep, modes, nodes):
    """(weight, per-mode node vectors) of each term of a separable coefficient."""
    out = []
    for term in sep.terms:
        factors = dict(term.factors)
        vecs = [np.broadcast_to(np.asarray(factors[m](z), float), z.shape).copy() if m in factors
                else np.ones(z.size) for m, z in zip(modes, nodes)]
        out.append((float(term.coef), vecs))
    return out


def _elimination(unknown, x_name: str, D1: np.ndarray):
    """Boundary rows C (2, n), data g (2,) and the map Z (n, n-2) of homogeneous conditions."""
    n = D1.shape[0]
    C, g = np.zeros((2, n)), np.zeros(2)
    for side, bc in enumerate(unknown.boundary[x_name]):
        node = 0 if side == 0 else n - 1
        C[side] = np.eye(n)[node] if bc.kind == "value" else D1[node]
        g[side] = 0.0 if bc.value.is_zero else bc.value.constant_value
    B, interior = np.array([0, n - 1]), np.arange(1, n - 1)
    Z = np.zeros((n, n - 2))
    Z[interior, np.arange(n - 2)] = 1.0
    Z[B] = -np.linalg.solve(C[:, B], C[:, interior])
    return C, g, Z


def _lift(C: np.ndarray, g: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """A function on the nodes ``xs`` (n,) meeting the two boundary rows ``C @ l = g``.

    ``a + b (x - x0)`` where it can; two gradient conditions fix only its slope (the system with
    ``1`` in the basis is singular), so there ``b (x - x0) + c (x - x0)**2``.
    """
    s = xs - xs[0]
    for basis in (np.stack([np.ones_like(xs), s], axis=1), np.stack([s, s * s], axis=1)):
        M = C @ basis
        if abs(np.linalg.det(M)) > 1e-12 * float(np.abs(M).max()) ** 2:
            break
    return basis @ np.linalg.solve(M, g)


def compile_pde_system(problem, bases: dict, *, rounding: float = 1e-13) -> PdeSystem:
    """The split system of ``problem`` on the nodes of ``bases`` (coordinate -> Basis1D, time excluded).

    ``rounding`` is the relative Frobenius accuracy of the initial value's TT-SVD.
    """
    x, unknown, p_k = _structure(problem)
    params = [c.name for c in problem.coordinates if c.name not in (problem.time, x.name)]
    modes = [x.name] + ([p_k] if p_k else []) + [p for p in params if p != p_k]
    grid = [np.asarray(bases[m].nodes, dtype=float) for m in modes]
    D1 = bases[x.name].derivative
    C, g, Z = _elimination(unknown, x.name, D1)
    xs = grid[0]
    lift = _lift(C, g, xs)
    A = (D1 @ D1 @ Z)[1:-1]
    diffusion, terms, mass = None, [], None
    for monomial, sep in problem.equations[0].polynomial.items():
        orders = _orders(problem, monomial)
        vecs = _vectors(problem, sep, modes, grid)
        if orders == (-1,):
            mass = vecs[0][0]
        elif orders == (2,) and diffusion is None:
            weight, vs = vecs[0]
            diffusion = -weight * (vs[1] if p_k else np.ones(1))
        else:
            terms += [(w, v, orders) for w, v in vecs]
    scale = 1.0 / mass  # the equation reads mass*der(u) + sum of monomials = 0
    terms = [(-w * scale, v, o) for w, v, o in terms]
    mesh = np.meshgrid(*grid, indexing="ij")
    u0 = np.broadcast_to(unknown.initial.evaluate(**dict(zip(modes, mesh))), mesh[0].shape)
    w0 = (u0 - lift.reshape((-1,) + (1,) * (len(modes) - 1)))[1:-1]
    initial = tt_from_full(np.ascontiguousarray(w0, dtype=float), rounding * float(np.linalg.norm(w0)))
    t = problem.time_coordinate.domain
    return PdeSystem(modes, grid, A, Z, D1, lift, diffusion * scale, terms, initial, (float(t[0]), float(t[1])))
