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

The coordinates and constants sections are parsed by :mod:`.spec_coordinates`, the name,
description, solver and output sections by :mod:`.spec_options`, the checks across sections are
:mod:`.spec_checks`; the unknowns and equations, which need all names, are parsed here.
"""

from __future__ import annotations

import pathlib
from typing import Any, Iterable

from ..errors import SpecError
from .checker import RESERVED_NAMES, Checker, NameRegistry, show_value
from .events import parse_events
from .expressions import ParseOptions, Separable, format_monomial, parse_equation, parse_expression
from .model import Boundary, Coordinate, Equation, Problem, SolverOptions, Unknown
from .second_order import INITIAL_KEYS, rate_name, reduce_to_first_order
from .spec_checks import assign_space_roles, check_steady, check_time_derivatives
from .spec_coordinates import parse_constants, parse_coordinate, parse_coordinate_names, parse_time
from .switches import with_switch_elements
from .spec_options import default_name, parse_description, parse_output, parse_problem_name, parse_solver
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


TOP_LEVEL_KEYS = ("name", "description", "coordinates", "time", "constants", "unknowns", "equations", "events", "solver",
                  "output")
UNKNOWN_KEYS = ("initial", "boundary")
BOUNDARY_SIDES = ("low", "high")


# ----------------------------------------------------------------------------------------------
# unknowns and equations
# ----------------------------------------------------------------------------------------------
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


def _parse_unknown(check: Checker, name: str, body: dict, names: ParseOptions) -> tuple[Unknown, ...]:
    """The unknown, and for ``initial: {value, rate}`` its rate unknown after it (``names``: what
    expressions may name)."""
    path = f"unknowns.{name}.initial"
    boundary = _parse_boundary(check, name, body.get("boundary"), names)
    if names.time is None:  # steady: parse_spec has checked there is no initial value
        return (Unknown(name, Separable(()), "", boundary),)
    raw = check.require(body, "initial", f"unknowns.{name}")
    if isinstance(raw, dict):  # a second-order unknown: {value: x0, rate: v0}
        raw = check.mapping(raw, path, INITIAL_KEYS)
        value = check.require(raw, "value", path)
        rate = _parse_initial(check, name, check.require(raw, "rate", path), f"{path}.rate", names)
        first = _parse_initial(check, name, value, f"{path}.value", names)
        return (Unknown(name, *first, boundary), Unknown(rate_name(name), *rate, rate_of=name))
    return (Unknown(name, *_parse_initial(check, name, raw, path, names), boundary),)


def _parse_initial(check: Checker, name: str, raw: Any, path: str, names: ParseOptions) -> tuple[Separable, str]:
    """An initial value: a number or an expression of the non-time coordinates; (value, text)."""
    if isinstance(raw, bool) or not isinstance(raw, (int, float, str)):
        expected = "a number or an expression string" + (", or {value: ..., rate: ...} for der(u, t, 2)"
                                                         if path.endswith("initial") else "")
        raise check.error(path, f"expected {expected}, got {show_value(raw)}")
    text = raw if isinstance(raw, str) else repr(raw)
    poly = parse_expression(text, names, where=f"{check.source}: {path}", allow_der=False)
    if poly.unknowns:
        found = ", ".join(sorted(poly.unknowns))
        raise check.error(path, f"the initial value of '{name}' must not depend on unknowns, found {found} in '{text}'")
    initial = poly.coefficient(())
    if names.time in initial.coordinates:
        raise check.error(
            path, f"the initial value of '{name}' must not depend on the time coordinate '{names.time}', got '{text}'"
        )
    return initial, text if isinstance(raw, str) else str(raw)


def _parse_boundary(check: Checker, name: str, value: Any, names: ParseOptions) -> dict:
    """``{x: {low: v, high: {gradient: g}}}`` -> {x: (Boundary, Boundary)}."""
    if value is None:
        return {}
    path = f"unknowns.{name}.boundary"
    section = check.mapping(value, path)
    out = {}
    time = names.time
    for coord, sides in section.items():
        cpath = f"{path}.{coord}"
        if coord not in names.coordinates:
            raise check.error(cpath, f"{coord!r} is not a coordinate ({', '.join(names.coordinates)})")
        if time is not None and coord == time:
            raise check.error(cpath, f"'{time}' is the time coordinate: its condition is the initial value")
        sides = check.mapping(sides, cpath, BOUNDARY_SIDES)
        out[coord] = tuple(_parse_boundary_side(check, coord, side, check.require(sides, side, cpath),
                                                f"{cpath}.{side}", names) for side in BOUNDARY_SIDES)
    return out


def _parse_boundary_side(check: Checker, coord: str, side: str, raw: Any, spath: str, names: ParseOptions) -> Boundary:
    """The condition at one end of a space coordinate: a value, or ``{gradient: g}``."""
    kind = "value"
    if isinstance(raw, dict):
        raw = check.mapping(raw, spath, ("gradient",))
        raw = check.require(raw, "gradient", spath)
        kind = "gradient"
    if isinstance(raw, bool) or not isinstance(raw, (int, float, str)):
        raise check.error(spath, f"expected a number, an expression or {{gradient: ...}}, got {show_value(raw)}")
    text = raw if isinstance(raw, str) else repr(raw)
    poly = parse_expression(text, names, where=f"{check.source}: {spath}", allow_der=False)
    if poly.unknowns:
        raise check.error(spath, f"a boundary value must not depend on unknowns, got '{text}'")
    sep = poly.coefficient(())
    if sep.joints:
        raise check.error(spath, f"a boundary value must be a sum of products of one-coordinate functions; "
                                 f"'{sep.joints[0].function_text()}' in '{text}' is not separable")
    if coord in sep.coordinates or (names.time is not None and names.time in sep.coordinates):
        raise check.error(spath, f"a boundary value at the {side} end of {coord!r} may depend on the other "
                                 f"non-time coordinates only, got '{text}'")
    return Boundary(kind, sep, text)


def _parse_equations(check: Checker, value: Any, names: ParseOptions, rates: dict[str, str]) -> tuple[Equation, ...]:
    unknowns, time = names.unknowns, names.time
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
        poly = parse_equation(text, names, where=f"{check.source}: {path}", allow_space_derivatives=True)
        equations.append(Equation(index, text, poly))
    if time is not None:  # der(x, t, 2): the first-order system with the rates
        equations, errors = reduce_to_first_order(equations, rates, time)
        if errors:
            raise check.error("", errors[0])
    if time is None:
        check_steady(check, equations, unknowns)
    else:
        check_time_derivatives(check, equations, unknowns, time)
    return tuple(equations)


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
    data = _load_document(check, text)
    problem_name = parse_problem_name(check, data, default_name(source, name))
    names = NameRegistry(check)
    coordinate_bodies = parse_coordinate_names(check, names, data["coordinates"])
    coordinate_names = list(coordinate_bodies)
    constants = parse_constants(check, names, data.get("constants"))
    time = parse_time(check, data, coordinate_names)
    coordinates = tuple(parse_coordinate(check, n, body, time, constants) for n, body in coordinate_bodies.items())
    unknown_bodies = _parse_unknown_names(check, names, data["unknowns"])
    rates = _rate_names(check, names, unknown_bodies, time)
    if time is None and any("initial" in body for body in unknown_bodies.values()):
        raise check.error("time", f"no coordinate is named 't'; add 'time: <name>' naming the time coordinate "
                                  f"(coordinates: {', '.join(coordinate_names)}), or remove the initial values "
                                  f"for a steady problem")
    context = ParseOptions(coordinates=coordinate_names, constants=constants,
                           unknowns=list(unknown_bodies) + list(rates.values()), time=time, where="",
                           domains={c.name: tuple(c.domain) for c in coordinates})
    parsed = [_parse_unknown(check, n, body, context) for n, body in unknown_bodies.items()]
    unknowns = tuple(u[0] for u in parsed) + tuple(u[1] for u in parsed if len(u) > 1)
    equations = _parse_equations(check, data["equations"], context, rates)
    coordinates = assign_space_roles(check, coordinates, unknowns, equations, time)
    coordinates = with_switch_elements(coordinates, equations, time)
    if time is None and not any(c.role == "space" for c in coordinates):
        raise check.error("time", "no coordinate is named 't' and no equation has a space derivative: name the time "
                                  "coordinate ('t' or 'time: <name>') for an initial-value problem, or add "
                                  "der(u, x, 2) for a steady one")
    events = parse_events(check, names, data.get("events"), context, any(c.role == "space" for c in coordinates))

    problem = Problem(
        name=problem_name,
        description=parse_description(check, data.get("description")),
        coordinates=coordinates,
        time=time,
        constants=constants,
        unknowns=unknowns,
        equations=equations,
        solver=parse_solver(check, data.get("solver")),
        output=parse_output(check, data, problem_name),
        source_text=text,
        source=source,
        events=events,
    )
    check_derivatives_linear(problem)
    if not allow_nonlinear:
        check_linear(problem)
    return problem


def _load_document(check: Checker, text: str) -> dict:
    """The YAML mapping of a spec, with its top-level keys checked and the required ones present."""
    data = load_yaml(text, check.source)
    if not isinstance(data, dict):
        found = "an empty document" if data is None else show_value(data)
        raise check.error("", f"expected a YAML mapping with keys {', '.join(TOP_LEVEL_KEYS)}, got {found}")
    check.mapping(data, "", TOP_LEVEL_KEYS)
    for key in ("coordinates", "unknowns", "equations"):
        check.require(data, key, "")
    return data


def _rate_names(check: Checker, names: NameRegistry, unknown_bodies: dict[str, dict], time: str | None) -> dict:
    """``{unknown: rate unknown}`` of the second-order unknowns (``initial: {value, rate}``), registered as names."""
    rates = {}
    for name, body in unknown_bodies.items():
        if isinstance(body.get("initial"), dict) and time is not None:
            rate = rate_name(name)
            if rate in names.owner:
                raise check.error(f"unknowns.{name}.initial", f"the rate of {name!r} is the unknown {rate!r}, a name "
                                                              f"already used by {names.owner[rate]}; rename that")
            names.owner[rate] = f"unknowns.{name}.initial.rate"
            rates[name] = rate
    return rates


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
