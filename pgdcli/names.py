"""What a name may be, in a spec and in a codebook file, and how any text is shown safely.

Names travel from a spec into a codebook file, and from a file into generated C and GLSL, into
terminals and into file names. One set of rules serves both ends: a spec is refused when a name
breaks them, and a codebook file whose names break them is refused as corrupt (it was not written
by pgdcli, or was altered since). Standard library only: every layer and the lean query path use it.
"""

from __future__ import annotations

import keyword
import re

__all__ = ["IDENTIFIER", "PROBLEM_NAME", "MAX_NAME_LENGTH", "MAX_PROBLEM_NAME_LENGTH", "identifier_problem",
           "problem_name_problem", "printable"]

#: Longest coordinate, unknown or constant name.
MAX_NAME_LENGTH = 64
#: Longest problem name (it becomes a file name and part of C identifiers).
MAX_PROBLEM_NAME_LENGTH = 128
#: Coordinate, unknown and constant names: C and Python identifiers of ASCII letters, digits, '_'.
IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: Problem names: letters, digits, '_', '.', '-' (a file name that cannot leave its folder).
PROBLEM_NAME = re.compile(r"[A-Za-z0-9_.-]+")

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def identifier_problem(name: object) -> str | None:
    """Why ``name`` is not a valid coordinate/unknown name (one phrase), or None when it is."""
    if not isinstance(name, str):
        return f"expected a name, got {type(name).__name__}"
    if len(name) > MAX_NAME_LENGTH:
        return f"a name of {len(name)} characters (at most {MAX_NAME_LENGTH})"
    if not IDENTIFIER.fullmatch(name):
        return "expected a letter or '_' followed by letters, digits or '_'"
    if keyword.iskeyword(name):
        return "a Python keyword"
    return None


def problem_name_problem(name: object) -> str | None:
    """Why ``name`` is not a valid problem name (one phrase), or None when it is."""
    if not isinstance(name, str):
        return f"expected a string, got {type(name).__name__}"
    if len(name) > MAX_PROBLEM_NAME_LENGTH:
        return f"a name of {len(name)} characters (at most {MAX_PROBLEM_NAME_LENGTH})"
    if not PROBLEM_NAME.fullmatch(name):
        return "expected letters, digits, '_', '.' or '-' only"
    return None


def printable(text: object, limit: int = 300) -> str:
    """``text`` safe for a terminal and a one-line message: control characters shown escaped.

    Escape sequences (``\\x1b[2J`` clears a screen), newlines, carriage returns and
    bidirectional overrides become ``\\x1b``-style escapes; at most ``limit`` characters.
    """
    text = str(text)
    if len(text) > limit:
        text = text[: limit - 3] + "..."
    return _CONTROL.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), text)
