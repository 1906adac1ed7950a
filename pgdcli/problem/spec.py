"""YAML problem specification -> validated :class:`Problem`.

This is the only module that imports yaml. A spec looks like::

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
"""

from __future__ import annotations

import dataclasses
import keyword
import math
import pathlib
import re
import reprlib
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np
import yaml

from ..errors import SpecError
from .second_order import INITIAL_KEYS, rate_name, reduce_to_first_order
from .expressions import (
    BUILTIN_NAMES,
    Polynomial,
    Separable,
    evaluate_constant,
    format_monomial,
    parse_equation,
    parse_expression,
)

__all__ = [
    "Coordinate",
    "Unknown",
    "Equation",
    "SolverOptions",
    "Problem",
    "RESERVED_NAMES",
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
MAX_SPEC_BYTES = 1 << 20  # a spec file's largest size (shipped specs: < 3 KiB)
MAX_SPEC_NODES = 100_000  # YAML nodes after expanding aliases (shipped specs: < 300)

#: Names that may not be used for coordinates, constants or unknowns: built-ins of
#: expressions, and command-line option names (``pgd eval --k 1`` must not clash).
RESERVED_NAMES = frozenset(
    BUILTIN_NAMES
    | {"format", "field", "points", "help", "version", "output", "seed", "samples", "jobs", "kind", "method"}
)

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = _REPR.maxlong = 80
_REPR.maxdict = _REPR.maxlist = _REPR.maxtuple = _REPR.maxset = 6
_REPR.maxlevel = 3
_PROBLEM_NAME = re.compile(r"[A-Za-z0-9_.-]+")


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
    method: str = "auto"  # 'auto' | 'pgd' (linear enrichment) | 'march' (separated time march)
    max_rank: int = 400  # march: cap on every tensor-train rank
    max_steps: int = 20000  # march: cap on accepted + rejected time steps
    time_slabs: int | str = "auto"  # time basis: 'auto' (march: one slab per accepted step; pgd: 1) or a count


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


# ----------------------------------------------------------------------------------------------
# YAML loading
# ----------------------------------------------------------------------------------------------
class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate mapping keys (PyYAML silently keeps the last)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        if isinstance(node, yaml.MappingNode):
            first_line: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # '<<' merges may legitimately be overridden
                key = self.construct_object(key_node, deep=True)
                try:
                    seen = key in first_line
                except TypeError:
                    continue  # unhashable key: the base class reports it
                if seen:
                    raise yaml.constructor.ConstructorError(
                        None,
                        None,
                        f"duplicate key {key!r} (first defined at line {first_line[key] + 1})",
                        key_node.start_mark,
                    )
                first_line[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep=deep)


def _load_yaml(text: str, source: str) -> Any:
    """Parse YAML text; any YAML error becomes one line with its line number.

    The text is bounded (:data:`MAX_SPEC_BYTES`), and its node graph is checked
    (:func:`_check_expansion`) *before* any Python value is built: an alias
    bomb is refused in milliseconds, not expanded.
    """
    if len(text) > MAX_SPEC_BYTES:
        raise SpecError(f"{source}: the spec has {len(text)} characters, more than the limit of {MAX_SPEC_BYTES}")
    loader = None
    try:
        loader = _StrictLoader(text)  # checks the characters already
        node = loader.get_single_node()
        if node is None:
            return None
        _check_expansion(node, source)
        try:
            return loader.construct_document(node)
        except (AttributeError, TypeError, KeyError, IndexError) as exc:
            # PyYAML's constructors assume well-formed tagged scalars: `!!timestamp x` raises
            # AttributeError and `!!bool maybe` KeyError from inside PyYAML
            raise SpecError(f"{source}: invalid YAML: a tagged value cannot be built "
                            f"({type(exc).__name__}: {' '.join(str(exc)[:120].split())}); "
                            f"remove the '!!' tags") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        problem = " ".join(str(problem)[:200].split())
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        raise SpecError(f"{source}: {where}invalid YAML: {problem}") from None
    except RecursionError:
        raise SpecError(f"{source}: invalid YAML: nested too deeply") from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits (Python's int limit)
        raise SpecError(f"{source}: invalid YAML: {' '.join(str(exc)[:200].split())}") from None
    finally:
        if loader is not None:
            loader.dispose()


def _children(node) -> list:
    """The child nodes of a YAML node (keys and values of a mapping)."""
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _expanded_sizes(root) -> dict:
    """id(node) -> number of nodes below it with every alias expanded (iterative: no recursion limit).

    Raises SpecError for a node that contains itself (a recursive anchor).
    """
    sizes: dict = {}
    open_nodes: set = set()
    stack = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if children_done:
            open_nodes.discard(key)
            total = 1
            for child in _children(node):
                total = min(total + sizes[id(child)], 1 << 62)
            sizes[key] = total
            continue
        if key in sizes:
            continue
        if key in open_nodes:
            raise SpecError(f"line {node.start_mark.line + 1}: a YAML anchor refers to itself")
        open_nodes.add(key)
        stack.append((node, True))
        stack.extend((child, False) for child in _children(node) if id(child) not in sizes)
    return sizes


def _check_expansion(root, source: str) -> None:
    """Refuse a document whose nodes, aliases expanded, exceed :data:`MAX_SPEC_NODES`, naming the key."""
    try:
        sizes = _expanded_sizes(root)
    except SpecError as exc:
        raise SpecError(f"{source}: {exc}") from None
    if sizes[id(root)] <= MAX_SPEC_NODES:
        return
    path, node = [], root
    while True:  # down to the deepest key that is too large by itself
        items = node.value if isinstance(node, yaml.MappingNode) else list(enumerate(node.value)) \
            if isinstance(node, yaml.SequenceNode) else []
        big = [(k, v) for k, v in items if sizes[id(v)] > MAX_SPEC_NODES]
        if not big:
            break
        key, node = big[0]
        path.append(str(key.value)[:40] if isinstance(key, yaml.Node) else f"[{key}]")
    where = ".".join(path).replace(".[", "[") or "the document"
    raise SpecError(f"{source}: {where}: the YAML expands to more than {MAX_SPEC_NODES} values (anchors and "
                    f"aliases repeat their content); a spec needs far fewer")


# ----------------------------------------------------------------------------------------------
# small validators: each raises SpecError("<source>: <path>: ...")
# ----------------------------------------------------------------------------------------------
def _show(value: Any) -> str:
    """A found value for a message: YAML-like spelling, shortened."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "nothing (null)"
    # reprlib stops after a few items and characters: a huge value is never spelled out in full
    text = _REPR.repr(value) if not isinstance(value, dict) else "a mapping " + _REPR.repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


class _Checker:
    """Builds messages prefixed with the source; one per parse."""

    def __init__(self, source: str) -> None:
        self.source = source

    def error(self, path: str, message: str) -> SpecError:
        return SpecError(f"{self.source}: {path}: {message}" if path else f"{self.source}: {message}")

    def mapping(self, value: Any, path: str, allowed: Iterable[str] | None = None, *, empty_ok: bool = True) -> dict:
        """A mapping (None counts as empty), with only the allowed keys."""
        if value is None:
            value = {}
        if not isinstance(value, dict):
            raise self.error(path, f"expected a mapping, got {_show(value)}")
        if not value and not empty_ok:
            raise self.error(path, "expected a non-empty mapping, got an empty one")
        if allowed is not None:
            allowed = tuple(allowed)
            for key in value:
                if key not in allowed:
                    hint = " (a YAML boolean: quote the key)" if isinstance(key, bool) else ""
                    raise self.error(path, f"unknown key {_show(key)}{hint} (allowed: {', '.join(allowed)})")
        return value

    def require(self, mapping: dict, key: str, path: str) -> Any:
        if key not in mapping:
            raise self.error(path, f"missing required key '{key}'")
        return mapping[key]

    def number(self, value: Any, path: str) -> float:
        """A finite number; numeric strings count (PyYAML reads 1e-8 as a string)."""
        if isinstance(value, bool):
            raise self.error(path, f"expected a number, got {_show(value)}")
        if isinstance(value, (int, float)):
            try:
                number = float(value)
            except OverflowError:  # an integer beyond float's range: not finite either
                number = math.inf
        elif isinstance(value, str):
            try:
                number = float(value.strip())
            except ValueError:
                raise self.error(path, f"expected a number, got {_show(value)}") from None
        else:
            raise self.error(path, f"expected a number, got {_show(value)}")
        if not math.isfinite(number):
            raise self.error(path, f"expected a finite number, got {_show(value)}")
        return number

    def integer(self, value: Any, path: str, low: int, high: int | None = None) -> int:
        """An integer in [low, high]; integral floats and numeric strings count, 3.5 does not."""
        expected = f"an integer >= {low}" if high is None else f"an integer from {low} to {high}"
        if isinstance(value, bool):
            raise self.error(path, f"expected {expected}, got {_show(value)}")
        if isinstance(value, int):
            result = value
        else:
            try:
                number = self.number(value, path)
            except SpecError:
                raise self.error(path, f"expected {expected}, got {_show(value)}") from None
            if not number.is_integer():
                raise self.error(path, f"expected {expected}, got {_show(value)}")
            result = int(number)
        if result < low or (high is not None and result > high):
            raise self.error(path, f"expected {expected}, got {_show(value)}")
        return result

    def choice(self, value: Any, path: str, choices: Iterable[str]) -> str:
        choices = tuple(choices)
        if not isinstance(value, str) or value not in choices:
            raise self.error(path, f"expected one of {', '.join(choices)}, got {_show(value)}")
        return value

    def text(self, value: Any, path: str) -> str:
        if not isinstance(value, str):
            raise self.error(path, f"expected a string, got {_show(value)}")
        return value


class _Names:
    """Validates names and keeps them unique across coordinates, constants and unknowns."""

    def __init__(self, check: _Checker) -> None:
        self.check = check
        self.owner: dict[str, str] = {}

    def add(self, key: Any, section: str) -> str:
        check = self.check
        if isinstance(key, bool):
            raise check.error(
                section,
                f"name {_show(key)} is a YAML boolean (unquoted yes/no/on/off/true/false);"
                " quote the name, e.g. 'on'",
            )
        if not isinstance(key, str):
            raise check.error(section, f"expected a name, got {_show(key)}; quote it or start it with a letter")
        path = f"{section}.{key}"
        if not _NAME.fullmatch(key):
            raise check.error(
                path, f"invalid name '{key}': expected a letter or '_' followed by letters, digits or '_'"
            )
        if keyword.iskeyword(key):
            raise check.error(path, f"'{key}' is a Python keyword and cannot be used in expressions; rename it")
        if key in RESERVED_NAMES:
            raise check.error(path, f"'{key}' is reserved (reserved names: {', '.join(sorted(RESERVED_NAMES))})")
        if key in self.owner:
            raise check.error(path, f"name '{key}' is already used by {self.owner[key]}")
        self.owner[key] = path
        return key


# ----------------------------------------------------------------------------------------------
# sections
# ----------------------------------------------------------------------------------------------
def _default_name(source: str, name: str | None) -> str:
    if name is not None:
        return name
    if source.startswith("<"):
        return "problem"
    return pathlib.Path(source).stem


def _parse_problem_name(check: _Checker, data: dict, default: str) -> str:
    if "name" not in data:
        if not _PROBLEM_NAME.fullmatch(default):
            raise check.error(
                "name", f"the default name '{default}' (from the file name) is not valid; add a 'name:' key"
            )
        return default
    value = data["name"]
    if not isinstance(value, str):
        raise check.error("name", f"expected a string of letters, digits, '_', '.', '-', got {_show(value)}; quote it")
    if not _PROBLEM_NAME.fullmatch(value):
        raise check.error("name", f"expected letters, digits, '_', '.' or '-' only, got {_show(value)}")
    return value


def _parse_description(check: _Checker, value: Any) -> str:
    if value is None:
        return ""
    return check.text(value, "description").strip()


def _parse_coordinate_names(check: _Checker, names: _Names, value: Any) -> dict[str, dict]:
    """Names and raw bodies of the coordinates (bodies need the constants)."""
    section = check.mapping(value, "coordinates", empty_ok=False)
    bodies = {}
    for key, body in section.items():
        name = names.add(key, "coordinates")
        bodies[name] = check.mapping(body, f"coordinates.{name}", COORDINATE_KEYS)
    return bodies


def _parse_constants(check: _Checker, names: _Names, value: Any) -> dict[str, float]:
    """Constants in order; each may use numbers, pi and the constants before it."""
    constants: dict[str, float] = {}
    for key, raw in check.mapping(value, "constants").items():
        name = names.add(key, "constants")
        path = f"constants.{name}"
        if isinstance(raw, bool) or not isinstance(raw, (int, float, str)):
            raise check.error(path, f"expected a number or an expression string, got {_show(raw)}")
        constants[name] = evaluate_constant(raw, constants=constants, where=f"{check.source}: {path}")
    return constants


def _parse_bound(check: _Checker, value: Any, path: str, constants: dict[str, float]) -> float:
    # numbers, numeric strings such as "1e-8", and expressions such as "2*pi" or "T/2"
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise check.error(path, f"expected a number, got {_show(value)}")
    return evaluate_constant(value, constants=constants, where=f"{check.source}: {path}")


def _parse_coordinate(check: _Checker, name: str, body: dict, time: str, constants: dict[str, float]) -> Coordinate:
    path = f"coordinates.{name}"
    domain = check.require(body, "domain", path)
    if not isinstance(domain, list) or len(domain) != 2:
        raise check.error(f"{path}.domain", f"expected [low, high], got {_show(domain)}")
    low = _parse_bound(check, domain[0], f"{path}.domain", constants)
    high = _parse_bound(check, domain[1], f"{path}.domain", constants)
    if not low < high:
        raise check.error(f"{path}.domain", f"expected [low, high] with low < high, got {_show(domain)}")
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
                                           f"got {_show(value)}") from None
    return Coordinate(name, (low, high), nodes, discretization, role, breakpoints=breakpoints)


def _parse_elements(check: _Checker, body: dict, path: str, domain: tuple, discretization: str, role: str) -> tuple:
    """``elements: N``: N equal elements (Chebyshev parameters only), as breakpoints; () for one."""
    if "elements" not in body:
        return ()
    count = check.integer(body["elements"], f"{path}.elements", 1, MAX_NODES)
    if count > 1 and (discretization != "chebyshev" or role == "time"):
        raise check.error(f"{path}.elements", "elements are for chebyshev parameter coordinates (time: "
                                              "solver.time_slabs; linear: add nodes)")
    return () if count == 1 else tuple(float(v) for v in np.linspace(domain[0], domain[1], count + 1))


def _parse_time(check: _Checker, data: dict, coordinate_names: list[str]) -> str | None:
    """The time coordinate: ``time:`` if given, else one named 't'; None (steady) without either."""
    listing = ", ".join(coordinate_names)
    if "time" not in data:
        return "t" if "t" in coordinate_names else None
    value = data["time"]
    if value is None:  # 'time: null': steady, even with a coordinate named 't'
        return None
    if isinstance(value, bool):
        raise check.error("time", f"got the YAML boolean {_show(value)}; quote the coordinate name")
    if not isinstance(value, str) or value not in coordinate_names:
        raise check.error("time", f"expected the name of a coordinate ({listing}) or null (steady), got {_show(value)}")
    return value


def _parse_unknown_names(check: _Checker, names: _Names, value: Any) -> dict[str, dict]:
    section = check.mapping(value, "unknowns", empty_ok=False)
    bodies = {}
    for key, body in section.items():
        name = names.add(key, "unknowns")
        path = f"unknowns.{name}"
        if not isinstance(body, dict):
            raise check.error(path, f"expected a mapping with key 'initial', e.g. {{initial: 0}}, got {_show(body)}")
        bodies[name] = check.mapping(body, path, UNKNOWN_KEYS)
    return bodies


def _parse_unknown(
    check: _Checker, name: str, body: dict, *, coordinates: list[str], constants: dict[str, float], unknowns: list[str], time: str
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


def _parse_initial(check: _Checker, name: str, raw: Any, path: str, *, coordinates: list[str],
                   constants: dict[str, float], unknowns: list[str], time: str) -> tuple[Separable, str]:
    """An initial value: a number or an expression of the non-time coordinates; (value, text)."""
    if isinstance(raw, bool) or not isinstance(raw, (int, float, str)):
        expected = "a number or an expression string" + (", or {value: ..., rate: ...} for der(u, t, 2)"
                                                         if path.endswith("initial") else "")
        raise check.error(path, f"expected {expected}, got {_show(raw)}")
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


def _parse_boundary(check: _Checker, name: str, value: Any, *, coordinates: list[str], constants: dict[str, float],
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
                raise check.error(spath, f"expected a number, an expression or {{gradient: ...}}, got {_show(raw)}")
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


def _assign_space_roles(check: _Checker, coordinates: tuple, unknowns: tuple, equations: tuple, time: str) -> tuple:
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
    check: _Checker, value: Any, *, coordinates: list[str], constants: dict[str, float], unknowns: list[str], time: str,
    rates: dict[str, str] | None = None,
) -> tuple[Equation, ...]:
    rates = rates or {}
    declared = [u for u in unknowns if u not in rates.values()]
    if not isinstance(value, list):
        raise check.error("equations", f"expected a list of equation strings, got {_show(value)}")
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
                path, f"expected an equation string, got {_show(text)}; quote equations that contain ': '"
            )
        if not isinstance(text, str):
            raise check.error(path, f"expected an equation string like 'der(u) = -u', got {_show(text)}")
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


def _check_steady(check: _Checker, equations: list[Equation], unknowns: list[str]) -> None:
    """Without time every unknown must appear in some equation, or the system is singular."""
    appearing = {atom.unknown for equation in equations for atom in equation.polynomial.atoms}
    for name in unknowns:
        if name not in appearing:
            raise check.error("equations", f"unknown '{name}' appears in no equation of this steady problem "
                                           "(no time coordinate); each unknown needs an equation")


def _check_time_derivatives(check: _Checker, equations: list[Equation], unknowns: list[str], time: str) -> None:
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


def _parse_solver(check: _Checker, value: Any) -> SolverOptions:
    allowed = [f.name for f in dataclasses.fields(SolverOptions)]
    section = check.mapping(value, "solver", allowed)
    options: dict[str, Any] = {}
    for key in ("tolerance", "fixed_point_tolerance"):
        if key in section:
            number = check.number(section[key], f"solver.{key}")
            if not 0 < number < 1:
                raise check.error(f"solver.{key}", f"expected a number in (0, 1), got {_show(section[key])}")
            options[key] = number
    if "relative_tolerance" in section:
        number = check.number(section["relative_tolerance"], "solver.relative_tolerance")
        if not 0 <= number < 1:
            raise check.error("solver.relative_tolerance",
                              f"expected a number in [0, 1), got {_show(section['relative_tolerance'])}")
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
                raise check.error("solver.time_slabs", f"expected 'auto' or an integer >= 1, got {_show(value)}") from None
    if "update" in section:
        if not isinstance(section["update"], bool):
            raise check.error("solver.update", f"expected true or false, got {_show(section['update'])}")
        options["update"] = section["update"]
    return SolverOptions(**options)


def _parse_output(check: _Checker, data: dict, name: str) -> pathlib.Path:
    if data.get("output") is None:
        return pathlib.Path("codebooks") / f"{name}.h5"
    value = data["output"]
    if not isinstance(value, str) or not value.strip():
        raise check.error("output", f"expected a non-empty file path, got {_show(value)}")
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
                    continue  # u*der(u, x): a valid nonlinear PDE, which the solver refuses (not supported yet)
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
    check = _Checker(source)
    data = _load_yaml(text, source)
    if not isinstance(data, dict):
        found = "an empty document" if data is None else _show(data)
        raise check.error("", f"expected a YAML mapping with keys {', '.join(TOP_LEVEL_KEYS)}, got {found}")
    check.mapping(data, "", TOP_LEVEL_KEYS)
    for key in ("coordinates", "unknowns", "equations"):
        check.require(data, key, "")

    problem_name = _parse_problem_name(check, data, _default_name(source, name))
    names = _Names(check)
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
