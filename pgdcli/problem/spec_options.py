"""The name, description, solver and output sections of a spec.

Part of :func:`pgdcli.problem.spec.parse_spec`: every error is a
:class:`~pgdcli.errors.SpecError` raised through the spec's :class:`~pgdcli.problem.checker.Checker`.
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Any

from ..errors import SpecError
from ..names import MAX_PROBLEM_NAME_LENGTH
from ..names import PROBLEM_NAME as PROBLEM_NAME_PATTERN
from .checker import Checker, show_value
from .model import SolverOptions
from .spec_coordinates import MAX_NODES

__all__ = ["FORMULATIONS", "METHODS", "MARCHES", "INTEGRATORS", "default_name", "parse_problem_name", "parse_description", "parse_solver",
           "parse_output"]

FORMULATIONS = ("minres", "galerkin")
METHODS = ("auto", "pgd", "amen", "march")
MARCHES = ("auto", "grid", "cross", "train")
#: The names of the time march's steppers and ``auto`` (``pgdcli.algorithms.steppers.CHOICES``, a layer
#: this one does not import; a test keeps them equal).
INTEGRATORS = ("auto", "dop853", "bs32", "rodas4")


def default_name(source: str, name: str | None) -> str:
    if name is not None:
        return name
    if source.startswith("<"):
        return "problem"
    return pathlib.Path(source).stem


def parse_problem_name(check: Checker, data: dict, default: str) -> str:
    if "name" not in data:
        if len(default) > MAX_PROBLEM_NAME_LENGTH or not PROBLEM_NAME_PATTERN.fullmatch(default):
            raise check.error(
                "name", f"the default name '{default}' (from the file name) is not valid; add a 'name:' key"
            )
        return default
    value = data["name"]
    if not isinstance(value, str):
        raise check.error("name", f"expected a string of letters, digits, '_', '.', '-', got {show_value(value)}; quote it")
    if len(value) > MAX_PROBLEM_NAME_LENGTH:
        raise check.error("name", f"a name of {len(value)} characters; at most {MAX_PROBLEM_NAME_LENGTH}")
    if not PROBLEM_NAME_PATTERN.fullmatch(value):
        raise check.error("name", f"expected letters, digits, '_', '.' or '-' only, got {show_value(value)}")
    return value


def parse_description(check: Checker, value: Any) -> str:
    if value is None:
        return ""
    return check.text(value, "description").strip()


def parse_solver(check: Checker, value: Any) -> SolverOptions:
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
    if "march" in section:
        options["march"] = check.choice(section["march"], "solver.march", MARCHES)
    if "integrator" in section:
        options["integrator"] = check.choice(section["integrator"], "solver.integrator", INTEGRATORS)
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


def parse_output(check: Checker, data: dict, name: str) -> pathlib.Path:
    if data.get("output") is None:
        return pathlib.Path("codebooks") / f"{name}.h5"
    value = data["output"]
    if not isinstance(value, str) or not value.strip():
        raise check.error("output", f"expected a non-empty file path, got {show_value(value)}")
    return pathlib.Path(value.strip())
