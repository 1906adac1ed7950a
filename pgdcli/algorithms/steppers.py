"""The registry of the time march's steppers: ``solver.integrator`` names one of :data:`METHODS`.

A new method is one module (a :class:`~pgdcli.algorithms.stepping.Stepper`: for an explicit pair a
subclass of :class:`~pgdcli.algorithms.runge_kutta.ExplicitRungeKutta` with its coefficients) and
one entry here; its name is also one of the spec's choices (``pgdcli.problem.spec_options.INTEGRATORS``,
in a layer that does not import this one; a test keeps the two equal).
"""

from __future__ import annotations

from .bogacki_shampine import BogackiShampine32
from .dop853 import Dop853
from .stepping import Stepper

__all__ = ["METHODS", "DEFAULT", "stepper"]

#: ``solver.integrator`` -> the stepper's class.
METHODS: dict[str, type[Stepper]] = {
    "dop853": Dop853,
    "bs32": BogackiShampine32,
}

DEFAULT = "dop853"


def stepper(name: str | None = None) -> Stepper:
    """The stepper named ``name`` (default :data:`DEFAULT`); ``KeyError`` names the choices."""
    key = DEFAULT if name is None else name
    if key not in METHODS:
        raise KeyError(f"unknown integrator {key!r}; expected one of {', '.join(METHODS)}")
    return METHODS[key]()
