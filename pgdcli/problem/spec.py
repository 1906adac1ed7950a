"""YAML problem specification -> validated :class:`Problem`.

The sections of a spec are parsed here; the data model is :mod:`.model`, the YAML input
:mod:`.yaml_input` (the only module that imports yaml), the validators :mod:`.checker`.
A spec looks like::

    name: relaxation
    coordinates:
      t: {domain: [0, 2], nodes: 32}
      k: {domain: [0.5, 5], nodes: 24}
    unknowns:
      u: {initial: 0}
    equations:
      - "der(u) = -k*u"

Every error is a :class:`~pgdcli.errors.SpecError` with a one-line message
``"<source>: <key path>: <what was expected>, got <what was found>"``.
Expressions are parsed by :mod:`pgdcli.problem.expressions` (never evaluated by Python).

Over 400 lines: one parser per section of the spec, each short; they share the checker and
the names registry and read best in the order of a spec file.
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Any, Iterable

import numpy as np

from ..errors import SpecError
from .checker import PROBLEM_NAME_PATTERN, RESERVED_NAMES, Checker, NameRegistry, show_value
from .expressions import Separable, evaluate_constant, format_monomial, parse_equation, parse_expression
from .model import Boundary, Coordinate, Equation, Problem, SolverOptions, Unknown
from .second_order import INITIAL_KEYS, rate_name, reduce_to_first_order
from .yaml_input import MAX_SPEC_BYTES, MAX_SPEC_NODES, load_yaml

__all__ = [
    "Coordinate",
    "Unknown",
    "Equation",
    "SolverOptions",
    "Problem",
    "RESERVED_NAMES",
    "MAX_SPEC_BYTES",
    "MAX_SPEC_NODES",
    "load_spec",
    "parse_spec",
    "check_linear",
]


TOP_LEVEL_KEYS = ("name", "description", "coordinates", "time", "constants", "unknowns", "equations", "solver", "output")
COORDINATE_KEYS = ("domain", "nodes", "discretization", "elements")
UNKNOWN_KEYS = ("initial", "boundary")
BOUNDARY_SIDES = ("low", "high")
DISCRETIZATIONS = ("chebyshev", "linear")
FORMULATIONS = ("minres", "galerkin")
METHODS = ("auto", "pgd", "march")
MAX_NODES = 2000
#: First node count of a coordinate whose nodes are chosen by the solver (``nodes: auto`` or none);
#: 2**k + 1 so that refinement (n -> 2n - 1) keeps the Chebyshev-Lobatto nodes nested.
AUTO_NODES = {"chebyshev": 9, "linear": 17}
# ----------------------------------------------------------------------------------------------
# sections
# ----------------------------------------------------------------------------------------------
def _default_name(source: str, name: str | None) -> str:
    if name is not None:
        return name
    if source.startswith("<"):
        return "problem"
    return pathlib.Path(source).stem


def _parse_problem_name(check: Checker, data: dict, default: str) -> str:
    if "name" not in data:
        if not PROBLEM_NAME_PATTERN.fullmatch(default):
            raise check.error(
                "name", f"the default name '{default}' (from the file name) is not valid; add a 'name:' key"
            )
        return default
    value = data["name"]
    if not isinstance(value, str):
        raise check.error("name", f"expected a string of letters, digits, '_', '.', '-', got {show_value(value)}; quote it")
    if not PROBLEM_NAME_PATTERN.fullmatch(value):
        raise check.error("name", f"expected letters, digits, '_', '.' or '-' only, got {show_value(value)}")
    return value


def _parse_description(check: Checker, value: Any) -> str:
    if value is None:
        return ""
    return check.text(value, "description").strip()


def _parse_coordinate_names(check: Checker, names: NameRegistry, value: Any) -> dict[str, dict]:
    """Names and raw bodies of the coordinates (bodies need the constants)."""
    section = check.mapping(value, "coordinates", empty_ok=False)
    bodies = {}
    for key, body in section.items():
        name = names.add(key, "coordinates")
        bodies[name] = check.mapping(body, f"coordinates.{name}", COORDINATE_KEYS)
    return bodies


def _parse_constants(check: Checker, names: NameRegistry, value: Any) -> dict[str, float]:
    """Constants in order; each may use numbers, pi and the constants before it."""
    constants: dict[str, float] = {}
    for key, raw in check.mapping(value, "constants").items():
        name = names.add(key, "constants")
        path = f"constants.{name}"
        if isinstance(raw, bool) or not isinstance(raw, (int, float, str)):
            raise check.error(path, f"expected a number or an expression string, got {show_value(raw)}")
        constants[name] = evaluate_constant(raw, constants=constants, where=f"{check.source}: {path}")
    return constants


def _parse_bound(check: Checker, value: Any, path: str, constants: dict[str, float]) -> float:
    # numbers, numeric strings such as "1e-8", and expressions such as "2*pi" or "T/2"
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise check.error(path, f"expected a number, got {show_value(value)}")
    return evaluate_constant(value, constants=constants, where=f"{check.source}: {path}")


def _parse_coordinate(check: Checker, name: str, body: dict, time: str, constants: dict[str, float]) -> Coordinate:
    path = f"coordinates.{name}"
    domain = check.require(body, "domain", path)
    if not isinstance(domain, list) or len(domain) != 2:
        raise check.error(f"{path}.domain", f"expected [low, high], got {show_value(domain)}")
    low = _parse_bound(check, domain[0], f"{path}.domain", constants)
    high = _parse_bound(check, domain[1], f"{path}.domain", constants)
    if not low < high:
        raise check.error(f"{path}.domain", f"expected [low, high] with low < high, got {show_value(domain)}")
    discretization = check.choice(body.get("discretization", "chebyshev"), f"{path}.discretization", DISCRETIZATIONS)
    role = "time" if name == time else "parameter"  # 'space' is decided from the equations
    breakpoints = _parse_elements(check, body, path, (low, high), discretization, role)
    value = body.get("nodes", "auto")
    if value == "auto" or value is None:
        return Coordinate(name, (low, high), AUTO_NODES[discretization], discretization, role, auto=True,
                          breakpoints=breakpoints)
    try:
        nodes = check.integer(value, f"{path}.nodes", 2, MAX_NODES)
    except SpecError:
        raise check.error(f"{path}.nodes", f"expected 'auto' or an integer in [2, {MAX_NODES}], "
                                           f"got {show_value(value)}") from None
    return Coordinate(name, (low, high), nodes, discretization, role, breakpoints=breakpoints)


def _parse_elements(check: Checker, body: dict, path: str, domain: tuple, discretization: str, role: str) -> tuple:
    """``elements: N``: N equal elements (Chebyshev parameters only), as breakpoints; () for one."""
    if "elements" not in body:
        return ()
    count = check.integer(body["elements"], f"{path}.elements", 1, MAX_NODES)
    if count > 1 and (discretization != "chebyshev" or role == "time"):
        raise check.error(f"{path}.elements", "elements are for chebyshev parameter coordinates (time: "
                                              "solver.time_slabs; linear: add nodes)")
    return () if count == 1 else tuple(float(v) for v in np.linspace(domain[0], domain[1], count + 1))


def _parse_time(check: Checker, data: dict, coordinate_names: list[str]) -> str | None:
    """The time coordinate: ``time:`` if given, else one named 't'; None (steady) without either."""
    listing = ", ".join(coordinate_names)
    if "time" not in data:
        return "t" if "t" in coordinate_names else None
    value = data["time"]
    if value is None:  # 'time: null': steady, even with a coordinate named 't'
        return None
    if isinstance(value, bool):
        raise check.error("time", f"got the YAML boolean {show_value(value)}; quote the coordinate name")
    if not isinstance(value, str) or value not in coordinate_names:
        raise check.error("time", f"expected the name of a coordinate ({listing}) or null (steady), got {show_value(value)}")
    return value


def _parse_unknown_names(check: Checker, names: NameRegistry, value: Any) -> dict[str, dict]:
    section = check.mapping(value, "unknowns", empty_ok=False)
    bodies = {}
    for key, body in section.items():
        name = names.add(key, "unknowns")
        path = f"unknowns.{name}"
        if not isinstance(body, dict):
            raise check.error(path, f"expected a mapping with key 'initial', e.g. {{initial: 0}}, got {show_value(body)}")
        bodies[name] = check.mapping(body, path, UNKNOWN_KEYS)
    return bodies


def _parse_unknown(
    check: Checker, name: str, body: dict, *, coordinates: list[str], constants: dict[str, float], unknowns: list[str], time: str
) -> tuple[Unknown, ...]:
    """The unknown, and for ``initial: {value, rate}`` its rate unknown after it."""
    path = f"unknowns.{name}.initial"
    boundary = _parse_boundary(check, name, body.get("boundary"), coordinates=coordinates, constants=constants,
                               unknowns=unknowns, time=time)
    if time is None:  # steady: parse_spec has checked there is no initial value
        return (Unknown(name, Separable(()), "", boundary),)
    raw = check.require(body, "initial", f"unknowns.{name}")
    if isinstance(raw, dict):  # a second-order unknown: {value: x0, rate: v0}
        raw = check.mapping(raw, path, INITIAL_KEYS)
        value = check.require(raw, "value", path)
        rate = _parse_initial(check, name, check.require(raw, "rate", path), f"{path}.rate", coordinates=coordinates,
                              constants=constants, unknowns=unknowns, time=time)
        first = _parse_initial(check, name, value, f"{path}.value", coordinates=coordinates, constants=constants,
                               unknowns=unknowns, time=time)
        return (Unknown(name, *first, boundary), Unknown(rate_name(name), *rate, rate_of=name))
    return (Unknown(name, *_parse_initial(check, name, raw, path, coordinates=coordinates, constants=constants,
                                          unknowns=unknowns, time=time), boundary),)


def _parse_initial(check: Checker, name: str, raw: Any, path: str, *, coordinates: list[str],
                   constants: dict[str, float], unknowns: list[str], time: str) -> tuple[Separable, str]:
    """An initial value: a number or an expression of the non-time coordinates; (value, text)."""
    if isinstance(raw, bool) or not isinstance(raw, (int, float, str)):
        expected = "a number or an expression string" + (", or {value: ..., rate: ...} for der(u, t, 2)"
                                                         if path.endswith("initial") else "")
        raise check.error(path, f"expected {expected}, got {show_value(raw)}")
    text = raw if isinstance(raw, str) else repr(raw)
    poly = parse_expression(
        text,
        coordinates=coordinates,
        constants=constants,
        unknowns=unknowns,
        time=time,
        where=f"{check.source}: {path}",
        allow_der=False,
    )
    if poly.unknowns:
        found = ", ".join(sorted(poly.unknowns))
        raise check.error(path, f"the initial value of '{name}' must not depend on unknowns, found {found} in '{text}'")
    initial = poly.coefficient(())
    if time in initial.coordinates:
        raise check.error(
            path, f"the initial value of '{name}' must not depend on the time coordinate '{time}', got '{text}'"
        )
    return initial, text if isinstance(raw, str) else str(raw)


def _parse_boundary(check: Checker, name: str, value: Any, *, coordinates: list[str], constants: dict[str, float],
                    unknowns: list[str], time: str) -> dict:
    """``{x: {low: v, high: {gradient: g}}}`` -> {x: (Boundary, Boundary)}."""
    if value is None:
        return {}
    path = f"unknowns.{name}.boundary"
    section = check.mapping(value, path)
    out = {}
    for coord, sides in section.items():
        cpath = f"{path}.{coord}"
        if coord not in coordinates:
            raise check.error(cpath, f"{coord!r} is not a coordinate ({', '.join(coordinates)})")
        if time is not None and coord == time:
            raise check.error(cpath, f"'{time}' is the time coordinate: its condition is the initial value")
        sides = check.mapping(sides, cpath, BOUNDARY_SIDES)
        pair = []
        for side in BOUNDARY_SIDES:
            spath = f"{cpath}.{side}"
            raw = check.require(sides, side, cpath)
            kind = "value"
            if isinstance(raw, dict):
                raw = check.mapping(raw, spath, ("gradient",))
                raw = check.require(raw, "gradient", spath)
                kind = "gradient"
            if isinstance(raw, bool) or not isinstance(raw, (int, float, str)):
                raise check.error(spath, f"expected a number, an expression or {{gradient: ...}}, got {show_value(raw)}")
            text = raw if isinstance(raw, str) else repr(raw)
            poly = parse_expression(text, coordinates=coordinates, constants=constants, unknowns=unknowns, time=time,
                                    where=f"{check.source}: {spath}", allow_der=False)
            if poly.unknowns:
                raise check.error(spath, f"a boundary value must not depend on unknowns, got '{text}'")
            sep = poly.coefficient(())
            if sep.joints:
                raise check.error(spath, f"a boundary value must be a sum of products of one-coordinate functions; "
                                         f"'{sep.joints[0].function_text()}' in '{text}' is not separable")
            if coord in sep.coordinates or (time is not None and time in sep.coordinates):
                raise check.error(spath, f"a boundary value at the {side} end of {coord!r} may depend on the other "
                                         f"non-time coordinates only, got '{text}'")
            pair.append(Boundary(kind, sep, text))
        out[coord] = tuple(pair)
    return out


def _assign_space_roles(check: Checker, coordinates: tuple, unknowns: tuple, equations: tuple, time: str) -> tuple:
    """Coordinates with space derivatives are 'space'; each needs boundary conditions where it is
    differentiated twice, and boundary conditions need derivatives."""
    second: dict[tuple[str, str], int] = {}
    space = set()
    for eq in equations:
        for atom in eq.polynomial.atoms:
            if atom.order > 0 and atom.coordinate != time:
                space.add(atom.coordinate)
                if atom.order == 2:
                    second.setdefault((atom.unknown, atom.coordinate), eq.index)
    for u in unknowns:
        for coord in u.boundary:
            if coord not in space:
                raise check.error(f"unknowns.{u.name}.boundary.{coord}",
                                  f"{coord!r} has no derivative in the equations: it is a parameter, not space")
    for (unknown, coord), index in second.items():
        u = next(x for x in unknowns if x.name == unknown)
        if coord not in u.boundary:
            raise check.error(f"unknowns.{unknown}.boundary",
                              f"missing the conditions at both ends of {coord!r} (der({unknown}, {coord}, 2) "
                              f"appears in equations[{index}]), e.g. {{{coord}: {{low: 0, high: 0}}}}")
    return tuple(dataclasses.replace(c, role="space") if c.name in space else c for c in coordinates)


def _parse_equations(
    check: Checker, value: Any, *, coordinates: list[str], constants: dict[str, float], unknowns: list[str], time: str,
    rates: dict[str, str] | None = None,
) -> tuple[Equation, ...]:
    rates = rates or {}
    declared = [u for u in unknowns if u not in rates.values()]
    if not isinstance(value, list):
        raise check.error("equations", f"expected a list of equation strings, got {show_value(value)}")
    if len(value) != len(declared):
        raise check.error(
            "equations",
            f"expected {len(declared)} equation(s), one per unknown ({', '.join(declared)}), got {len(value)}",
        )
    equations = []
    for index, text in enumerate(value):
        path = f"equations[{index}]"
        if isinstance(text, dict):
            raise check.error(
                path, f"expected an equation string, got {show_value(text)}; quote equations that contain ': '"
            )
        if not isinstance(text, str):
            raise check.error(path, f"expected an equation string like 'der(u) = -u', got {show_value(text)}")
        poly = parse_equation(
            text,
            coordinates=coordinates,
            constants=constants,
            unknowns=unknowns,
            time=time,
            where=f"{check.source}: {path}",
            allow_space_derivatives=True,
        )
        equations.append(Equation(index, text, poly))
    if time is not None:  # der(x, t, 2): the first-order system with the rates
        equations, errors = reduce_to_first_order(equations, rates, time)
        if errors:
            raise check.error("", errors[0])
    if time is None:
        _check_steady(check, equations, unknowns)
    else:
        _check_time_derivatives(check, equations, unknowns, time)
    return tuple(equations)


def _check_steady(check: Checker, equations: list[Equation], unknowns: list[str]) -> None:
    """Without time every unknown must appear in some equation, or the system is singular."""
    appearing = {atom.unknown for equation in equations for atom in equation.polynomial.atoms}
    for name in unknowns:
        if name not in appearing:
            raise check.error("equations", f"unknown '{name}' appears in no equation of this steady problem "
                                           "(no time coordinate); each unknown needs an equation")


def _check_time_derivatives(check: Checker, equations: list[Equation], unknowns: list[str], time: str) -> None:
    """First-order time derivatives only; one in every equation, of every unknown somewhere."""
    differentiated = set()
    for equation in equations:
        derivatives = [atom for atom in equation.polynomial.atoms if atom.order > 0 and atom.coordinate == time]
        for atom in derivatives:
            if atom.order > 1:
                raise check.error(
                    f"equations[{equation.index}]",
                    f"'{atom.text(time)}' in '{equation.text}': time derivatives of order 1 or 2 only"
                    " (write higher orders as first-order systems)",
                )
        if not derivatives:
            raise check.error(
                f"equations[{equation.index}]",
                f"no time derivative in '{equation.text}'; each equation must contain der(<unknown>)",
            )
        differentiated.update(atom.unknown for atom in derivatives)
    for name in unknowns:
        if name not in differentiated:
            raise check.error(
                "equations", f"unknown '{name}' never appears as der({name}); each unknown needs its time derivative"
            )


def _parse_solver(check: Checker, value: Any) -> SolverOptions:
    allowed = [f.name for f in dataclasses.fields(SolverOptions)]
    section = check.mapping(value, "solver", allowed)
    options: dict[str, Any] = {}
    for key in ("tolerance", "fixed_point_tolerance"):
        if key in section:
            number = check.number(section[key], f"solver.{key}")
            if not 0 < number < 1:
                raise check.error(f"solver.{key}", f"expected a number in (0, 1), got {show_value(section[key])}")
            options[key] = number
    if "relative_tolerance" in section:
        number = check.number(section["relative_tolerance"], "solver.relative_tolerance")
        if not 0 <= number < 1:
            raise check.error("solver.relative_tolerance",
                              f"expected a number in [0, 1), got {show_value(section['relative_tolerance'])}")
        options["relative_tolerance"] = number
    if "max_nodes" in section:
        options["max_nodes"] = check.integer(section["max_nodes"], "solver.max_nodes", 3, MAX_NODES)
    for key in ("max_modes", "max_fixed_point_iterations"):
        if key in section:
            options[key] = check.integer(section[key], f"solver.{key}", 1)
    for key in ("max_rank", "max_steps"):
        if key in section:
            options[key] = check.integer(section[key], f"solver.{key}", 1)
    if "formulation" in section:
        options["formulation"] = check.choice(section["formulation"], "solver.formulation", FORMULATIONS)
    if "method" in section:
        options["method"] = check.choice(section["method"], "solver.method", METHODS)
    if "time_slabs" in section:
        value = section["time_slabs"]
        if value == "auto":
            options["time_slabs"] = "auto"
        else:
            try:
                options["time_slabs"] = check.integer(value, "solver.time_slabs", 1)
            except SpecError:
                raise check.error("solver.time_slabs", f"expected 'auto' or an integer >= 1, got {show_value(value)}") from None
    if "update" in section:
        if not isinstance(section["update"], bool):
            raise check.error("solver.update", f"expected true or false, got {show_value(section['update'])}")
        options["update"] = section["update"]
    return SolverOptions(**options)


def _parse_output(check: Checker, data: dict, name: str) -> pathlib.Path:
    if data.get("output") is None:
        return pathlib.Path("codebooks") / f"{name}.h5"
    value = data["output"]
    if not isinstance(value, str) or not value.strip():
        raise check.error("output", f"expected a non-empty file path, got {show_value(value)}")
    return pathlib.Path(value.strip())


# ----------------------------------------------------------------------------------------------
# public API
# ----------------------------------------------------------------------------------------------
def check_derivatives_linear(problem: Problem) -> None:
    """Reject a time derivative multiplied by an unknown (``der(u)*u``): no solver handles it.

    A space derivative times an unknown (``u*der(u, x)``, Burgers) is a nonlinear PDE: valid,
    and refused by the solver with that reason."""
    for equation in problem.equations:
        for monomial in equation.polynomial:
            if len(monomial) >= 2 and any(atom.order > 0 for atom in monomial):
                if all(atom.order == 0 or atom.coordinate != problem.time for atom in monomial):
                    continue  # u*der(u, x): a valid nonlinear PDE (pgdcli.algorithms.pde_system decides)
                raise SpecError(
                    f"{problem.source}: equations[{equation.index}]: term '{format_monomial(monomial, problem.time)}'"
                    f" in '{equation.text}' multiplies a derivative by an unknown; der(...) must appear linearly"
                )


def check_linear(problem_or_equations: Problem | Iterable[Equation], *, source: str = "<string>") -> None:
    """Reject equations that are nonlinear in the unknowns (the linear solver's limit).

    Parameters
    ----------
    problem_or_equations : Problem or iterable of Equation
    source : str
        Message prefix when equations are given (a Problem brings its own).

    Raises
    ------
    SpecError
        Naming the first monomial of degree >= 2, e.g. ``u*v`` or ``der(u)*u``.
    """
    time = None
    equations = problem_or_equations
    if isinstance(problem_or_equations, Problem):
        source, time, equations = problem_or_equations.source, problem_or_equations.time, problem_or_equations.equations
    for equation in equations:
        for monomial in equation.polynomial:
            if len(monomial) >= 2:
                raise SpecError(
                    f"{source}: equations[{equation.index}]: nonlinear term '{format_monomial(monomial, time)}'"
                    f" in '{equation.text}'; only equations linear in the unknowns are supported"
                )


def parse_spec(text: str, *, source: str = "<string>", name: str | None = None, allow_nonlinear: bool = True) -> Problem:
    """Validate a YAML problem specification.

    Parameters
    ----------
    text : str
        The YAML text.
    source : str
        File path or ``'<string>'``: the prefix of every error message.
    name : str, optional
        Problem name used when the spec has no ``name`` key (default: the stem
        of ``source``, or ``'problem'`` if source is not a path).
    allow_nonlinear : bool
        Skip :func:`check_linear` (for a solver of nonlinear equations).

    Returns
    -------
    Problem

    Raises
    ------
    SpecError
        For any invalid YAML, key, value or expression.
    """
    check = Checker(source)
    data = load_yaml(text, source)
    if not isinstance(data, dict):
        found = "an empty document" if data is None else show_value(data)
        raise check.error("", f"expected a YAML mapping with keys {', '.join(TOP_LEVEL_KEYS)}, got {found}")
    check.mapping(data, "", TOP_LEVEL_KEYS)
    for key in ("coordinates", "unknowns", "equations"):
        check.require(data, key, "")

    problem_name = _parse_problem_name(check, data, _default_name(source, name))
    names = NameRegistry(check)
    coordinate_bodies = _parse_coordinate_names(check, names, data["coordinates"])
    coordinate_names = list(coordinate_bodies)
    constants = _parse_constants(check, names, data.get("constants"))
    time = _parse_time(check, data, coordinate_names)
    coordinates = tuple(
        _parse_coordinate(check, n, body, time, constants) for n, body in coordinate_bodies.items()
    )
    unknown_bodies = _parse_unknown_names(check, names, data["unknowns"])
    rates = {}
    for name, body in unknown_bodies.items():  # second-order unknowns: their rates are unknowns too
        if isinstance(body.get("initial"), dict) and time is not None:
            rate = rate_name(name)
            if rate in names.owner:
                raise check.error(f"unknowns.{name}.initial", f"the rate of {name!r} is the unknown {rate!r}, a name "
                                                              f"already used by {names.owner[rate]}; rename that")
            names.owner[rate] = f"unknowns.{name}.initial.rate"
            rates[name] = rate
    unknown_names = list(unknown_bodies) + list(rates.values())
    if time is None and any("initial" in body for body in unknown_bodies.values()):
        raise check.error("time", f"no coordinate is named 't'; add 'time: <name>' naming the time coordinate "
                                  f"(coordinates: {', '.join(coordinate_names)}), or remove the initial values "
                                  f"for a steady problem")
    context = dict(coordinates=coordinate_names, constants=constants, unknowns=unknown_names, time=time)
    parsed = [_parse_unknown(check, n, body, **context) for n, body in unknown_bodies.items()]
    unknowns = tuple(u[0] for u in parsed) + tuple(u[1] for u in parsed if len(u) > 1)
    equations = _parse_equations(check, data["equations"], **context, rates=rates)
    coordinates = _assign_space_roles(check, coordinates, unknowns, equations, time)
    if time is None and not any(c.role == "space" for c in coordinates):
        raise check.error("time", "no coordinate is named 't' and no equation has a space derivative: name the time "
                                  "coordinate ('t' or 'time: <name>') for an initial-value problem, or add "
                                  "der(u, x, 2) for a steady one")

    problem = Problem(
        name=problem_name,
        description=_parse_description(check, data.get("description")),
        coordinates=coordinates,
        time=time,
        constants=constants,
        unknowns=unknowns,
        equations=equations,
        solver=_parse_solver(check, data.get("solver")),
        output=_parse_output(check, data, problem_name),
        source_text=text,
        source=source,
    )
    check_derivatives_linear(problem)
    if not allow_nonlinear:
        check_linear(problem)
    return problem


def load_spec(path: str | pathlib.Path, *, allow_nonlinear: bool = True) -> Problem:
    """Read and validate a YAML problem file.

    Parameters
    ----------
    path : str or path-like
    allow_nonlinear : bool
        See :func:`parse_spec`.

    Returns
    -------
    Problem

    Raises
    ------
    SpecError
        If the file cannot be read or the spec is invalid.
    """
    path = pathlib.Path(path)
    try:
        with open(path, "rb") as handle:  # at most one byte past the limit (a FIFO or /dev/zero too)
            data = handle.read(MAX_SPEC_BYTES + 1)
        if len(data) > MAX_SPEC_BYTES:
            raise SpecError(f"{path}: cannot read problem file: larger than {MAX_SPEC_BYTES} bytes")
        text = data.decode("utf-8")
    except FileNotFoundError:
        raise SpecError(f"{path}: cannot read problem file: no such file") from None
    except IsADirectoryError:
        raise SpecError(f"{path}: cannot read problem file: it is a directory") from None
    except UnicodeDecodeError:
        raise SpecError(f"{path}: cannot read problem file: not UTF-8 text") from None
    except OSError as exc:
        raise SpecError(f"{path}: cannot read problem file: {exc.strerror or exc}") from None
    return parse_spec(text, source=str(path), name=path.stem, allow_nonlinear=allow_nonlinear)
