"""A reaction-diffusion system on the nodes, split for the exponential march (:mod:`.pde_march`).

The state is the interior values ``w_s`` of every species on the grid ``(x, [y], parameters)``
(Chebyshev-Lobatto nodes of the codebook's bases; the modes of :class:`.pde_structure.PdeStructure`),
``u_s = Z w_s + L_s`` (:mod:`.pde_boundary`: the boundary values eliminated, a lift carrying the
data). Each species' equation is split into

    w_s' = sum_a c_sa(p) A_sa w_s + N_s(t, u)

the diffusion (``A_sa`` the eliminated ``d^2/dx_a^2`` of that species' conditions, ``c_sa`` its
coefficient over its mass, on the parameter grid), which the march integrates exactly through the
eigendecompositions of the ``A_sa`` (their Kronecker sum in two space coordinates), and the rest
``N_s`` (reaction, advection, sources, the lift's diffusion), evaluated explicitly.

What is refused is decided by :func:`.pde_structure.pde_structure` (the form) and here (boundary
data that disagree at a corner).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SolverError
from ..problem.general import is_general, tree_of
from ..problem.separable import TimeSplit
from .pde_boundary import boundary_rows, check_corners, elimination, lift_basis, lift_grid, mode_product
from .pde_phi import Eigen
from .pde_structure import SCOPE, PdeStructure, pde_refusal, pde_structure

__all__ = ["PdeSystem", "Species", "Term", "compile_pde_system", "pde_refusal", "SCOPE"]


@dataclass
class Term:
    """One monomial of ``N_s``: ``coefficient * prod(atoms)`` (the sign and the mass folded in later).

    ``atoms``: ``('u', species, axis or None, order)`` for an unknown or its derivative along a space
    axis, ``('g', tree)`` for a function of the unknowns (:mod:`pgdcli.problem.general`).
    """

    coefficient: object  # Separable
    atoms: tuple
    steady: bool


@dataclass
class Species:
    """One unknown's operators on the grid.

    Attributes
    ----------
    name : str
    Z : list of ndarray (n_a, n_a - 2)
        Per space axis, the elimination of its homogeneous conditions.
    eigen : list of Eigen
        Per space axis, of ``A_a = (D_a^2 Z_a)[interior]``.
    diffusion : list of ndarray
        Per space axis, ``c_a / m`` on the grid (broadcastable; size 1 along the space axes).
    lift : ndarray
        ``L`` on the full grid (broadcastable).
    source : ndarray
        ``sum_a c_a (D_a^2 L)[interior] / m``, broadcastable to the interior grid.
    scale : ndarray
        ``-1 / m`` on the grid (broadcastable): the factor of ``N_s``'s monomials.
    terms : list of Term
    """

    name: str
    Z: list
    eigen: list
    diffusion: list
    lift: np.ndarray
    source: np.ndarray
    scale: np.ndarray
    terms: list


@dataclass
class PdeSystem:
    """The split system on the nodes (see the module docstring).

    Attributes
    ----------
    modes : list of str
        ``[space coordinates..., parameters...]``.
    nodes : list of ndarray
        Their nodes.
    space : int
        How many of the first modes are space coordinates.
    D1 : list of ndarray (n_a, n_a)
        ``d/dx_a`` per space axis.
    species : list of Species
    initial : ndarray (q, m_x, [m_y], n_p...)
        ``w(t0)`` of every species.
    t_span : (float, float)
    time : str
        The time coordinate's name (in coefficients and functions of the unknowns).
    diffusion_modes : int
        The first modes (space axes, then parameters) the diffusion coefficients vary along.
    """

    modes: list
    nodes: list
    space: int
    D1: list
    species: list
    initial: np.ndarray
    t_span: tuple
    time: str
    diffusion_modes: int
    _steady: dict = field(default_factory=dict, repr=False)

    @property
    def shape(self) -> tuple:
        """The full grid."""
        return tuple(z.size for z in self.nodes)

    @property
    def interior_shape(self) -> tuple:
        return tuple(n - 2 if k < self.space else n for k, n in enumerate(self.shape))

    @property
    def interior(self) -> tuple:
        """Index of the interior nodes of the full grid."""
        return (slice(1, -1),) * self.space

    def values(self, t: float | None = None) -> dict:
        """Coordinate name -> nodes shaped to broadcast along their mode (and the time)."""
        d = len(self.modes)
        out = {m: z.reshape([-1 if j == k else 1 for j in range(d)]) for k, (m, z) in enumerate(zip(self.modes,
                                                                                                     self.nodes))}
        if t is not None:
            out[self.time] = np.asarray(float(t))
        return out

    def on_grid(self, sep, t: float | None = None) -> np.ndarray:
        """A coefficient on the grid, broadcastable to it (``ndim`` of the grid)."""
        return _grid_data(self.values(t), sep, len(self.modes))

    def coefficient(self, s: int, term: Term, t: float) -> np.ndarray:
        """``-coefficient / m_s`` of a monomial of species ``s`` on the grid at time ``t`` (the parts free of
        time evaluated once)."""
        key = id(term)
        if key not in self._steady:
            if term.steady:
                self._steady[key] = self.on_grid(term.coefficient) * self.species[s].scale
            else:
                self._steady[key] = TimeSplit(term.coefficient, self.time, self.values())
        coef = self._steady[key]
        if term.steady:
            return coef
        v = coef(t)
        return v.reshape((1,) * (len(self.modes) - v.ndim) + v.shape) * self.species[s].scale


def _grid_data(values: dict, sep, d: int) -> np.ndarray:
    """``sep`` at the broadcast nodes ``values``, with ``d`` axes (size 1 along those it does not depend on)."""
    v = np.asarray(sep.evaluate(**{k: values[k] for k in sep.coordinates}), dtype=float)
    return v.reshape((1,) * (d - v.ndim) + v.shape)


def _atoms(monomial, structure: PdeStructure) -> tuple:
    out = []
    for a in monomial:
        if is_general(a):
            out.append(("g", tree_of(a)))
        else:
            axis = structure.space.index(a.coordinate) if a.order else None
            out.append(("u", structure.species.index(a.unknown), axis, a.order))
    return tuple(out)


def compile_pde_system(problem, bases: dict, *, rounding: float = 1e-13,
                       corner_tolerance: float | None = None) -> PdeSystem:
    """The split system of ``problem`` on the nodes of ``bases`` (coordinate -> Basis1D, time excluded).

    ``corner_tolerance``: the largest disagreement of boundary data at a corner accepted (default: the
    problem's tolerance). ``rounding`` is unused (kept for callers of the one-species march).
    """
    structure = pde_structure(problem)
    modes = structure.modes
    grid = [np.asarray(bases[m].nodes, dtype=float) for m in modes]
    nd, d = len(structure.space), len(modes)
    D1 = [np.asarray(bases[x].derivative, dtype=float) for x in structure.space]
    t0, t1 = problem.time_coordinate.domain
    system = PdeSystem(modes, grid, nd, D1, [], np.empty(0), (float(t0), float(t1)), problem.time,
                       nd + len(structure.diffusion_params))
    values = system.values()
    tol = problem.solver.tolerance if corner_tolerance is None else corner_tolerance
    eigens: dict = {}
    initial = []
    for s, name in enumerate(structure.species):
        unknown = problem.unknowns[s]
        C, Z, Phi, eig, data = [], [], [], [], []
        for a, x in enumerate(structure.space):
            ends = unknown.boundary[x]
            kinds = tuple(bc.kind for bc in ends)
            C.append(boundary_rows(kinds, D1[a]))
            Z.append(elimination(C[-1]))
            Phi.append(lift_basis(C[-1], grid[a]))
            key = (a, kinds)
            if key not in eigens:
                eigens[key] = Eigen((D1[a] @ D1[a] @ Z[-1])[1:-1])
            eig.append(eigens[key])
            data.append(tuple(_grid_data(values, bc.value, d) for bc in ends))
        try:
            check_corners(C, data, list(structure.space), [problem.coordinate(x).domain for x in structure.space],
                          tol, name)
        except SolverError as exc:
            raise SolverError(f"{problem.source}: {exc}") from None
        lift = lift_grid(C, Phi, data)
        mass = system.on_grid(structure.mass[s])
        diffusion = [system.on_grid(c) / mass for c in structure.diffusion[s]]
        source = 0.0
        for a in range(nd):
            source = source + diffusion[a] * mode_product(D1[a] @ D1[a], lift, a)
        source = np.asarray(source)[system.interior] if np.ndim(source) else np.zeros((1,) * d)
        terms = [Term(sep, _atoms(monomial, structure), problem.time not in sep.coordinates)
                 for monomial, sep in structure.terms[s]]
        system.species.append(Species(name, Z, eig, diffusion, lift, source, -1.0 / mass, terms))
        u0 = np.broadcast_to(_grid_data(values, unknown.initial, d), system.shape)
        initial.append((u0 - lift)[system.interior])
    system.initial = np.ascontiguousarray(np.stack(initial))
    return system
