"""Small validators for the spec's sections: each raises SpecError("<source>: <path>: ...").
"""

from __future__ import annotations

import keyword
import math
import reprlib
from typing import Any, Iterable

from ..errors import SpecError
from ..names import IDENTIFIER, MAX_NAME_LENGTH
from .expressions import BUILTIN_NAMES

__all__ = ["RESERVED_NAMES"]


#: Names that may not be used for coordinates, constants or unknowns: built-ins of
#: expressions, and command-line option names (``pgd eval --k 1`` must not clash).
RESERVED_NAMES = frozenset(
    BUILTIN_NAMES
    | {"format", "field", "points", "help", "version", "output", "seed", "samples", "jobs", "kind", "method"}
)

SHORT_REPR = reprlib.Repr()
SHORT_REPR.maxstring = SHORT_REPR.maxother = SHORT_REPR.maxlong = 80
SHORT_REPR.maxdict = SHORT_REPR.maxlist = SHORT_REPR.maxtuple = SHORT_REPR.maxset = 6
SHORT_REPR.maxlevel = 3
# ----------------------------------------------------------------------------------------------
# small validators: each raises SpecError("<source>: <path>: ...")
# ----------------------------------------------------------------------------------------------
def show_value(value: Any) -> str:
    """A found value for a message: YAML-like spelling, shortened."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "nothing (null)"
    # reprlib stops after a few items and characters: a huge value is never spelled out in full
    text = SHORT_REPR.repr(value) if not isinstance(value, dict) else "a mapping " + SHORT_REPR.repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


class Checker:
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
            raise self.error(path, f"expected a mapping, got {show_value(value)}")
        if not value and not empty_ok:
            raise self.error(path, "expected a non-empty mapping, got an empty one")
        if allowed is not None:
            allowed = tuple(allowed)
            for key in value:
                if key not in allowed:
                    hint = " (a YAML boolean: quote the key)" if isinstance(key, bool) else ""
                    raise self.error(path, f"unknown key {show_value(key)}{hint} (allowed: {', '.join(allowed)})")
        return value

    def require(self, mapping: dict, key: str, path: str) -> Any:
        if key not in mapping:
            raise self.error(path, f"missing required key '{key}'")
        return mapping[key]

    def number(self, value: Any, path: str) -> float:
        """A finite number; numeric strings count (PyYAML reads 1e-8 as a string)."""
        if isinstance(value, bool):
            raise self.error(path, f"expected a number, got {show_value(value)}")
        if isinstance(value, (int, float)):
            try:
                number = float(value)
            except OverflowError:  # an integer beyond float's range: not finite either
                number = math.inf
        elif isinstance(value, str):
            try:
                number = float(value.strip())
            except ValueError:
                raise self.error(path, f"expected a number, got {show_value(value)}") from None
        else:
            raise self.error(path, f"expected a number, got {show_value(value)}")
        if not math.isfinite(number):
            raise self.error(path, f"expected a finite number, got {show_value(value)}")
        return number

    def integer(self, value: Any, path: str, low: int, high: int | None = None) -> int:
        """An integer in [low, high]; integral floats and numeric strings count, 3.5 does not."""
        expected = f"an integer >= {low}" if high is None else f"an integer from {low} to {high}"
        if isinstance(value, bool):
            raise self.error(path, f"expected {expected}, got {show_value(value)}")
        if isinstance(value, int):
            result = value
        else:
            try:
                number = self.number(value, path)
            except SpecError:
                raise self.error(path, f"expected {expected}, got {show_value(value)}") from None
            if not number.is_integer():
                raise self.error(path, f"expected {expected}, got {show_value(value)}")
            result = int(number)
        if result < low or (high is not None and result > high):
            raise self.error(path, f"expected {expected}, got {show_value(value)}")
        return result

    def choice(self, value: Any, path: str, choices: Iterable[str]) -> str:
        choices = tuple(choices)
        if not isinstance(value, str) or value not in choices:
            raise self.error(path, f"expected one of {', '.join(choices)}, got {show_value(value)}")
        return value

    def text(self, value: Any, path: str) -> str:
        if not isinstance(value, str):
            raise self.error(path, f"expected a string, got {show_value(value)}")
        return value


class NameRegistry:
    """Validates names and keeps them unique across coordinates, constants and unknowns."""

    def __init__(self, check: Checker) -> None:
        self.check = check
        self.owner: dict[str, str] = {}

    def add(self, key: Any, section: str) -> str:
        check = self.check
        if isinstance(key, bool):
            raise check.error(
                section,
                f"name {show_value(key)} is a YAML boolean (unquoted yes/no/on/off/true/false);"
                " quote the name, e.g. 'on'",
            )
        if not isinstance(key, str):
            raise check.error(section, f"expected a name, got {show_value(key)}; quote it or start it with a letter")
        path = f"{section}.{key}"
        if len(key) > MAX_NAME_LENGTH:
            raise check.error(path, f"a name of {len(key)} characters; at most {MAX_NAME_LENGTH}")
        if not IDENTIFIER.fullmatch(key):
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
