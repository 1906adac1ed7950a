"""What the nonlinear PDE march takes: the structure of a problem, or one line saying why not.

The march (:mod:`.pde_march`) integrates reaction-diffusion systems in one or two space
coordinates: unknowns ``u_1 .. u_q`` (species), each with its own equation

    m_s der(u_s) = c_sx der(u_s, x, 2) [+ c_sy der(u_s, y, 2)] + N_s(t, x, y, p, u, der(u, .), der(u, ., 2))

where the mass ``m_s`` and the diffusion coefficients ``c_sa`` are functions of the parameters only
(constants, ``D``, ``eps**2``, ``(1 + a)*d``: any expression of the non-space, non-time
coordinates, positive), and ``N_s`` is any sum of products of the unknowns, their first and second
space derivatives and functions of them (``u*v**2``, ``-u*der(u, x)``, ``u*v/(1 + u)``, ``sin(u)``)
with coefficients in every coordinate, time included. Each unknown has value or gradient
conditions at both ends of every space coordinate, with data that may depend on the parameters and
on the other space coordinate.

:func:`pde_structure` returns the :class:`PdeStructure` or raises :class:`~pgdcli.errors.SolverError`
with one line naming the equation or key and what the march would need; :func:`pde_refusal` is the
same as a string (None when the form fits). Only the form is checked here; the compiled system
(:mod:`.pde_system`) checks the data on the nodes (boundary data that disagree at a corner).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ..discretization.basis import make_basis
from ..errors import SolverError
from ..problem.general import is_general
from ..problem.polynomial import format_monomial
from .pde_boundary import boundary_rows, check_corners

__all__ = ["PdeStructure", "pde_structure", "pde_refusal", "SCOPE", "MAX_SPACE"]

#: What the PDE march integrates, for refusals.
SCOPE = ("the PDE march takes one or two space coordinates and equations der(u) = c_x*der(u, x, 2) "
         "[+ c_y*der(u, y, 2)] + terms in the unknowns and their space derivatives, one per unknown, "
         "c a positive function of the parameters")
#: Most space coordinates.
MAX_SPACE = 2
#: Random parameter points (beside the corners and the center) where a diffusion coefficient's sign is checked.
SIGN_SAMPLES = 64
#: Nodes along each space coordinate where the boundary data are compared at the corners before solving.
CORNER_NODES = 17


@dataclass(frozen=True)
class PdeStructure:
    """The parts of a reaction-diffusion problem, per species.

    Attributes
    ----------
    space : tuple of str
        The space coordinates (one or two), in spec order.
    params : tuple of str
        The other non-time coordinates: first those a diffusion coefficient or a mass depends on, then
        the rest, each group in spec order (the train's mode order after the space coordinates).
    species : tuple of str
        The unknowns, in declared order.
    equation : tuple of int
        The index of each species' equation.
    mass : tuple of Separable
        Per species, the coefficient ``m_s`` of ``der(u_s)``.
    diffusion : tuple of tuple of Separable
        Per species and space coordinate, ``c_sa`` (already with the sign of the right-hand side).
    terms : tuple of tuple of (monomial, Separable)
        Per species, the rest in ``lhs - rhs`` form: ``m_s der(u_s) - sum_a c_sa der(u_s, a, 2) +
        sum terms = 0``.
    """

    space: tuple
    params: tuple
    species: tuple
    equation: tuple
    mass: tuple
    diffusion: tuple
    terms: tuple

    @property
    def modes(self) -> list:
        """The state's modes: space coordinates, then parameters."""
        return list(self.space) + list(self.params)

    @property
    def diffusion_params(self) -> list:
        """Parameters some diffusion coefficient or mass depends on (the first of :attr:`params`)."""
        used = set().union(*(c.coordinates for row in self.diffusion for c in row),
                           *(m.coordinates for m in self.mass))
        return [p for p in self.params if p in used]


def pde_refusal(problem) -> str | None:
    """Why the PDE march cannot take ``problem`` (one line), or None when its form fits."""
    try:
        pde_structure(problem)
    except SolverError as exc:
        return str(exc)
    return None


def _refuse(problem, what: str, where: str = "equations"):
    raise SolverError(f"{problem.source}: {where}: {what} ({SCOPE})")


def pde_structure(problem) -> PdeStructure:
    """The species, their diffusion and the rest of their equations; refuses what does not fit."""
    space = [c for c in problem.coordinates if c.role == "space"]
    if not 1 <= len(space) <= MAX_SPACE:
        _refuse(problem, f"{len(space)} space coordinates ({', '.join(c.name for c in space)}); "
                         f"at most {MAX_SPACE}", "coordinates")
    rates = [u for u in problem.unknowns if u.rate_of]
    if rates:  # the user wrote one unknown: say why there are two
        _refuse(problem, f"der({rates[0].rate_of}, t, 2) makes a system of {rates[0].rate_of} and its rate "
                         f"{rates[0].name} (second-order time derivatives are not supported in nonlinear PDEs)")
    for x in space:
        if x.discretization != "chebyshev" or len(x.breakpoints) > 2:
            _refuse(problem, f"space coordinate {x.name!r} must be one Chebyshev element", f"coordinates.{x.name}")
    names = [x.name for x in space]
    species = list(problem.unknown_names)
    owner_of = {}
    for eq in problem.equations:
        owner = _owner(problem, eq)
        if owner in owner_of:
            _refuse(problem, f"der({owner}) appears in equations[{owner_of[owner]}] and equations[{eq.index}]; "
                             f"one equation per unknown", f"equations[{eq.index}]")
        owner_of[owner] = eq.index
    missing = [u for u in species if u not in owner_of]
    if missing:
        _refuse(problem, f"no equation has der({missing[0]})")
    equation, mass, diffusion, terms = [], [], [], []
    for u in species:
        eq = problem.equations[owner_of[u]]
        m, c, rest = _split_equation(problem, eq, u, names, species)
        equation.append(eq.index)
        mass.append(m)
        diffusion.append(tuple(c))
        terms.append(tuple(rest))
        _check_boundary(problem, problem.unknowns[species.index(u)], names)
    used = set().union(*(s.coordinates for row in diffusion for s in row), *(s.coordinates for s in mass))
    others = [c.name for c in problem.coordinates if c.name != problem.time and c.name not in names]
    params = [p for p in others if p in used] + [p for p in others if p not in used]
    structure = PdeStructure(tuple(names), tuple(params), tuple(species), tuple(equation), tuple(mass),
                             tuple(diffusion), tuple(terms))
    _check_signs(problem, structure)
    if len(names) == 2:
        _check_corners(problem, structure)
    return structure


def _owner(problem, eq) -> str:
    """The unknown whose ``der()`` the equation holds (alone, linearly, once)."""
    owners = []
    for monomial in eq.polynomial:
        ders = [a for a in monomial if a.order and a.coordinate == problem.time]
        if ders and len(monomial) != 1:
            _refuse(problem, f"der({ders[0].unknown}) must appear alone and linearly, got "
                             f"'{format_monomial(monomial, problem.time)}'", f"equations[{eq.index}]")
        owners += [a.unknown for a in ders]
    if len(owners) != 1:
        what = "no der() of an unknown" if not owners else f"der() of {len(owners)} unknowns ({', '.join(owners)})"
        _refuse(problem, what, f"equations[{eq.index}]")
    return owners[0]


def _split_equation(problem, eq, u: str, space: list, species: list):
    """``(mass, [c_a per space coordinate], [(monomial, coefficient) of the rest])`` of ``u``'s equation."""
    where = f"equations[{eq.index}]"
    fixed = {problem.time, *space}
    mass, diffusion, rest = None, {}, []
    for monomial, sep in eq.polynomial.items():
        atoms = [a for a in monomial if not is_general(a)]
        if any(a.order > 2 for a in atoms):
            _refuse(problem, f"a space derivative of order above 2 in '{format_monomial(monomial)}'", where)
        if len(monomial) == 1 and monomial[0].coordinate == problem.time and monomial[0].order:
            mass = sep
            if sep.coordinates & fixed:
                _refuse(problem, f"the coefficient of der({u}) must not depend on {_names(sep.coordinates & fixed)}",
                        where)
            continue
        if len(monomial) == 1 and monomial[0].order == 2 and not is_general(monomial[0]):
            atom = monomial[0]
            if atom.unknown != u:
                _refuse(problem, f"cross-diffusion der({atom.unknown}, {atom.coordinate}, 2) in the equation of "
                                 f"{u} (each unknown's own diffusion only: an explicit one would need steps "
                                 f"~1/n^4 on n nodes)", where)
            if sep.coordinates & fixed:
                _refuse(problem, f"the diffusion coefficient of {u} along {atom.coordinate} must not depend on "
                                 f"{_names(sep.coordinates & fixed)}", where)
            diffusion[atom.coordinate] = -sep
            continue
        rest.append((monomial, sep))
    for x in space:
        if x not in diffusion:
            _refuse(problem, f"no diffusion term c*der({u}, {x}, 2) in the equation of {u}", where)
    return mass, [diffusion[x] for x in space], rest


def _names(names) -> str:
    return ", ".join(sorted(names))


def _check_boundary(problem, unknown, space: list) -> None:
    """Value or gradient conditions at both ends of every space coordinate."""
    for x in space:
        if unknown.boundary.get(x) is None:
            _refuse(problem, f"{unknown.name!r} needs conditions at both ends of {x}",
                    f"unknowns.{unknown.name}.boundary")
        for side, bc in zip(("low", "high"), unknown.boundary[x]):
            if bc.kind not in ("value", "gradient"):
                _refuse(problem, f"a {bc.kind} condition", f"unknowns.{unknown.name}.boundary.{x}.{side}")


def _check_signs(problem, structure: PdeStructure) -> None:
    """Masses of one sign, diffusion coefficients positive, at the corners, center and random points of their box."""
    for s, u in enumerate(structure.species):
        where = f"equations[{structure.equation[s]}]"
        mass = structure.mass[s]
        values, at = _samples(problem, mass)
        if not (np.all(values > 0) or np.all(values < 0)):
            low, high = int(np.argmin(values)), int(np.argmax(values))
            _refuse(problem, f"the coefficient of der({u}), {mass}, changes sign ({values[low]:.6g}{at(low)}, "
                             f"{values[high]:.6g}{at(high)}): it must not vanish", where)
        for x, c in zip(structure.space, structure.diffusion[s]):
            values, at = _samples(problem, c)
            if not np.all(values > 0):
                i = int(np.argmin(values))
                _refuse(problem, f"the diffusion coefficient of {u} along {x}, {c}, is {values[i]:.6g}{at(i)}: it "
                                 f"must be positive", where)


def _points(problem, names: list) -> np.ndarray:
    """The corners (up to 64), the center and random points of the named coordinates' box: (count, len(names))."""
    domains = [problem.coordinate(n).domain for n in names]
    corners = list(itertools.islice(itertools.product(*domains), 64)) + [tuple(np.mean(d) for d in domains)]
    rng = np.random.default_rng(0)
    count = len(corners) + (SIGN_SAMPLES if names else 0)
    return np.array(corners + [tuple(rng.uniform(*d) for d in domains) for _ in range(count - len(corners))],
                    dtype=float).reshape(count, len(names))


def _samples(problem, sep):
    """``sep`` at :func:`_points` of its coordinates, and ``at(i)``, the text ' at a=.., b=..' of point ``i``."""
    names = sorted(sep.coordinates)
    points = _points(problem, names)
    values = np.broadcast_to(np.asarray(sep.evaluate(**{n: points[:, i] for i, n in enumerate(names)}), float),
                             (points.shape[0],))

    def at(i: int) -> str:
        return "".join(f"{', ' if k else ' at '}{n}={points[i, k]:.6g}" for k, n in enumerate(names))

    return values, at


def _check_corners(problem, structure: PdeStructure) -> None:
    """Boundary data of the two space coordinates that agree at the corners (to the tolerance), at the
    corners, center and random points of the parameters' box: refused before solving, in one line."""
    axes = [make_basis("chebyshev", problem.coordinate(x).domain, CORNER_NODES) for x in structure.space]
    params = sorted({c for u in problem.unknowns for ends in u.boundary.values() for bc in ends
                     for c in bc.value.coordinates} - set(structure.space))
    points = _points(problem, params)
    values = {x: np.asarray(b.nodes).reshape([-1 if j == k else 1 for j in range(3)])
              for k, (x, b) in enumerate(zip(structure.space, axes))}
    values.update({p: points[:, k].reshape(1, 1, -1) for k, p in enumerate(params)})
    for unknown in problem.unknowns:
        C, data = [], []
        for a, x in enumerate(structure.space):
            ends = unknown.boundary[x]
            C.append(boundary_rows(tuple(bc.kind for bc in ends), np.asarray(axes[a].derivative)))
            data.append(tuple(_on(bc.value, values) for bc in ends))
        try:
            check_corners(C, data, list(structure.space), [problem.coordinate(x).domain for x in structure.space],
                          problem.solver.tolerance, unknown.name)
        except SolverError as exc:
            raise SolverError(f"{problem.source}: {exc}") from None


def _on(sep, values: dict) -> np.ndarray:
    v = np.asarray(sep.evaluate(**{k: values[k] for k in sep.coordinates}), dtype=float)
    return v.reshape((1,) * (3 - v.ndim) + v.shape)
