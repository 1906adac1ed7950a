"""pgdcli: Proper Generalized Decomposition codebooks for parametric dynamical systems.

Python API
----------
- :func:`load_spec` -- YAML spec file -> validated :class:`~pgdcli.problem.spec.Problem`
- :func:`solve` -- problem -> :class:`~pgdcli.driver.SolveResult` (``.codebook``, ``.converged``, ``.residuals``)
- :class:`Codebook` -- ``Codebook.load(path)``; ``codebook(t=..., k=...)`` -> {unknown: ndarray}
- :func:`fit` -- codebook + data -> :class:`~pgdcli.inference.fitting.FitResult` (parameter identification)

Submodules are imported lazily so that evaluating a codebook does not pay for
scipy or yaml.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__", "load_spec", "parse_spec", "solve", "verify", "Codebook", "PgdError"]
__all__ += ["fit"]  # parameter identification (pgdcli.inference.fitting)

_LAZY = {
    "load_spec": ("problem.spec", "load_spec"),
    "parse_spec": ("problem.spec", "parse_spec"),
    "Problem": ("problem.spec", "Problem"),
    "solve": ("driver", "solve"),
    "SolveResult": ("driver", "SolveResult"),
    "Status": ("algorithms.outcome", "Status"),
    "Codebook": ("codebook.codebook", "Codebook"),
    "verify": ("checks.verify", "verify"),
    "PgdError": ("errors", "PgdError"),
    "fit": ("inference.fitting", "fit"),
    "FitResult": ("inference.fitting", "FitResult"),
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(f"{__name__}.{module}"), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
