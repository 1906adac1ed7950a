"""The coordinates and constants sections of a spec: names, domains, node counts, elements, time.

Part of :func:`pgdcli.problem.spec.parse_spec`: every error is a
:class:`~pgdcli.errors.SpecError` raised through the spec's :class:`~pgdcli.problem.checker.Checker`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import SpecError
from .checker import Checker, NameRegistry, show_value
from .expressions import evaluate_constant
from .model import Coordinate

__all__ = ["COORDINATE_KEYS", "DISCRETIZATIONS", "MAX_NODES", "AUTO_NODES", "parse_coordinate_names",
           "parse_constants", "parse_coordinate", "parse_time"]

COORDINATE_KEYS = ("domain", "nodes", "discretization", "elements")
DISCRETIZATIONS = ("chebyshev", "linear")
MAX_NODES = 2000
#: First node count of a coordinate whose nodes are chosen by the solver (``nodes: auto`` or none);
#: 2**k + 1 so that refinement (n -> 2n - 1) keeps the Chebyshev-Lobatto nodes nested.
AUTO_NODES = {"chebyshev": 9, "linear": 17}


def parse_coordinate_names(check: Checker, names: NameRegistry, value: Any) -> dict[str, dict]:
    """Names and raw bodies of the coordinates (bodies need the constants)."""
    section = check.mapping(value, "coordinates", empty_ok=False)
    bodies = {}
    for key, body in section.items():
        name = names.add(key, "coordinates")
        bodies[name] = check.mapping(body, f"coordinates.{name}", COORDINATE_KEYS)
    return bodies


def parse_constants(check: Checker, names: NameRegistry, value: Any) -> dict[str, float]:
    """Constants in order; each may use numbers, pi and the constants before it."""
    constants: dict[str, float] = {}
    for key, raw in check.mapping(value, "constants").items():
        name = names.add(key, "constants")
        path = f"constants.{name}"
        if isinstance(raw, bool) or not isinstance(raw, (int, float, str)):
            raise check.error(path, f"expected a number or an expression string, got {show_value(raw)}")
        constants[name] = evaluate_constant(raw, constants=constants, where=f"{check.source}: {path}")
    return constants


def parse_bound(check: Checker, value: Any, path: str, constants: dict[str, float]) -> float:
    # numbers, numeric strings such as "1e-8", and expressions such as "2*pi" or "T/2"
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise check.error(path, f"expected a number, got {show_value(value)}")
    return evaluate_constant(value, constants=constants, where=f"{check.source}: {path}")


def parse_coordinate(check: Checker, name: str, body: dict, time: str, constants: dict[str, float]) -> Coordinate:
    path = f"coordinates.{name}"
    domain = check.require(body, "domain", path)
    if not isinstance(domain, list) or len(domain) != 2:
        raise check.error(f"{path}.domain", f"expected [low, high], got {show_value(domain)}")
    low = parse_bound(check, domain[0], f"{path}.domain", constants)
    high = parse_bound(check, domain[1], f"{path}.domain", constants)
    if not low < high:
        raise check.error(f"{path}.domain", f"expected [low, high] with low < high, got {show_value(domain)}")
    discretization = check.choice(body.get("discretization", "chebyshev"), f"{path}.discretization", DISCRETIZATIONS)
    role = "time" if name == time else "parameter"  # 'space' is decided from the equations
    breakpoints = parse_elements(check, body, path, (low, high), discretization, role)
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


def parse_elements(check: Checker, body: dict, path: str, domain: tuple, discretization: str, role: str) -> tuple:
    """``elements: N``: N equal elements (Chebyshev parameters only), as breakpoints; () for one."""
    if "elements" not in body:
        return ()
    count = check.integer(body["elements"], f"{path}.elements", 1, MAX_NODES)
    if count > 1 and (discretization != "chebyshev" or role == "time"):
        raise check.error(f"{path}.elements", "elements are for chebyshev parameter coordinates (time: "
                                              "solver.time_slabs; linear: add nodes)")
    return () if count == 1 else tuple(float(v) for v in np.linspace(domain[0], domain[1], count + 1))


def parse_time(check: Checker, data: dict, coordinate_names: list[str]) -> str | None:
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
