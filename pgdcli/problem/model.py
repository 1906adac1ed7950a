"""The parsed problem: coordinates, unknowns, equations, solver options (frozen dataclasses).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import pathlib

from .expressions import Polynomial, Separable

__all__ = ["Coordinate", "Unknown", "Equation", "SolverOptions", "Problem"]


# ----------------------------------------------------------------------------------------------
# data model
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Coordinate:
    """One coordinate of the problem: time or a parameter.

    Attributes
    ----------
    name : str
    domain : (float, float)
        ``low < high``.
    nodes : int
        Number of discretization nodes, 2 to 2000 (with ``auto``: the first count tried);
        with ``breakpoints``, per element.
    discretization : str
        ``'chebyshev'`` or ``'linear'``.
    role : str
        ``'time'``, ``'space'`` (differentiated in the equations) or ``'parameter'``.
    """

    name: str
    domain: tuple[float, float]
    nodes: int
    discretization: str = "chebyshev"
    role: str = "parameter"
    auto: bool = False  # nodes omitted or 'auto': the solver chooses them (pgdcli.adapt)
    breakpoints: tuple = ()  # elements of a Chebyshev parameter coordinate (ends included); () = one element


@dataclass(frozen=True)
class Boundary:
    """A boundary condition at one end of a space coordinate.

    Attributes
    ----------
    kind : str
        ``'value'`` (Dirichlet: u = value) or ``'gradient'`` (Neumann: du/dx = value).
    value : Separable
        A function of the coordinates other than this one and time.
    text : str
    """

    kind: str
    value: Separable
    text: str


@dataclass(frozen=True)
class Unknown:
    """An unknown with its initial value (a function of the non-time coordinates).

    ``boundary`` maps a space coordinate to its ``(low, high)`` :class:`Boundary` pair.
    """

    name: str
    initial: Separable
    initial_text: str
    boundary: dict = field(default_factory=dict, hash=False, compare=False)
    rate_of: str | None = None  # the rate unknown of a second-order unknown (pgdcli.problem.second_order): its name


@dataclass(frozen=True)
class Equation:
    """Equation ``index`` (0-based), as written and as ``lhs - rhs`` (= 0)."""

    index: int
    text: str
    polynomial: Polynomial


@dataclass(frozen=True)
class SolverOptions:
    """Solver settings; the defaults here are the only defaults."""

    tolerance: float = 1e-8  # bound on the codebook's error: |u - u_exact| <= tolerance + relative_tolerance |u|
    relative_tolerance: float = 0.0
    max_nodes: int = 129  # automatic resolution: cap on the nodes of a coordinate (all its elements)
    max_modes: int = 100
    formulation: str = "minres"
    fixed_point_tolerance: float = 1e-4
    max_fixed_point_iterations: int = 25
    update: bool = True
    method: str = "auto"  # 'auto' | 'pgd' (linear enrichment) | 'amen' (linear, tensor train) | 'march' (time march)
    max_rank: int = 400  # march: cap on every tensor-train rank
    max_steps: int = 20000  # march: cap on accepted + rejected time steps
    time_slabs: int | str = "auto"  # time basis: 'auto' (march: one slab per accepted step; pgd: 1) or a count
    march: str = "auto"  # ODE march state: 'auto' (the grid when it has at most 2^21 values) | 'grid' | 'train'
    integrator: str = "auto"  # ODE march: its stepper, 'auto' (dop853, rodas4 when stiff) | 'dop853' | 'bs32' | 'rodas4'


@dataclass(frozen=True)
class Problem:
    """A validated problem specification.

    Attributes
    ----------
    name, description : str
    coordinates : tuple of Coordinate
        In spec order, which is the dimension order of the codebook.
    time : str or None
        Name of the time coordinate; None for a steady problem (no ``der(u)``, no
        initial values), whose unknowns are functions of space and parameters only.
    constants : dict of str to float
    unknowns : tuple of Unknown
        In declared order, which is the output order.
    equations : tuple of Equation
    solver : SolverOptions
    output : pathlib.Path
    source_text : str
        The YAML text as given.
    source : str
        File path or ``'<string>'``, used in messages.
    events : tuple of pgdcli.problem.events.Event
        Named conditions whose first crossing in time is recorded (``events:``).
    """

    name: str
    description: str
    coordinates: tuple[Coordinate, ...]
    time: str | None
    constants: dict[str, float] = field(hash=False)
    unknowns: tuple[Unknown, ...]
    equations: tuple[Equation, ...]
    solver: SolverOptions
    output: pathlib.Path
    source_text: str
    source: str
    events: tuple = ()  # of pgdcli.problem.events.Event: conditions whose first crossing the codebook records

    def coordinate(self, name: str) -> Coordinate:
        """The coordinate called ``name`` (KeyError if there is none)."""
        for coordinate in self.coordinates:
            if coordinate.name == name:
                return coordinate
        raise KeyError(name)

    @property
    def coordinate_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.coordinates)

    @property
    def unknown_names(self) -> tuple[str, ...]:
        return tuple(u.name for u in self.unknowns)

    @property
    def steady(self) -> bool:
        """True when there is no time coordinate (an equilibrium problem)."""
        return self.time is None

    @property
    def time_coordinate(self) -> Coordinate | None:
        return None if self.time is None else self.coordinate(self.time)

    @property
    def parameter_coordinates(self) -> tuple[Coordinate, ...]:
        return tuple(c for c in self.coordinates if c.name != self.time)
