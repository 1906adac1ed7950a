"""pgdcli: Proper Generalized Decomposition codebooks for parametric dynamical systems.

Python API
----------
- :func:`load_spec`, :func:`parse_spec` -- YAML spec (file, text) -> validated :class:`Problem`
- :func:`solve` -- problem -> :class:`SolveResult` (``.codebook``, ``.converged``, ``.check``)
- :class:`Codebook` -- ``Codebook.load(path)``; ``codebook(t=..., k=...)`` -> {unknown: ndarray}
- :func:`verify` -- codebook -> :class:`VerifyReport` (against an independent reference)
- :func:`fit` -- codebook + data -> :class:`FitResult` (parameter identification)
- :class:`PgdError` -- the base of every error pgdcli raises on purpose (one-line message)

Submodules are imported lazily so that evaluating a codebook does not pay for
scipy or yaml.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

__all__ = ["__version__", "load_spec", "parse_spec", "solve", "verify", "fit", "Codebook", "Problem",
           "SolveResult", "Status", "VerifyReport", "FitResult", "PgdError"]

if TYPE_CHECKING:  # the names below, for type checkers and the API reference (imported lazily at run time)
    from .algorithms.outcome import Status
    from .checks.verify import VerifyReport, verify
    from .codebook.codebook import Codebook
    from .driver import SolveResult, solve
    from .errors import PgdError
    from .inference.fitting import FitResult, fit
    from .problem.spec import Problem, load_spec, parse_spec

_LAZY = {
    "load_spec": ("problem.spec", "load_spec"),
    "parse_spec": ("problem.spec", "parse_spec"),
    "Problem": ("problem.spec", "Problem"),
    "solve": ("driver", "solve"),
    "SolveResult": ("driver", "SolveResult"),
    "Status": ("algorithms.outcome", "Status"),
    "Codebook": ("codebook.codebook", "Codebook"),
    "verify": ("checks.verify", "verify"),
    "VerifyReport": ("checks.verify", "VerifyReport"),
    "PgdError": ("errors", "PgdError"),
    "fit": ("inference.fitting", "fit"),
    "FitResult": ("inference.fitting", "FitResult"),
}


def __getattr__(name: str):
    if name in _LAZY:
        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(f"{__name__}.{module}"), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
