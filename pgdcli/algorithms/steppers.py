"""The registry of the time march's steppers: ``solver.integrator`` names one of :data:`METHODS` or ``auto``.

A new method is one module (a :class:`~pgdcli.algorithms.stepping.Stepper`: for an explicit pair a
subclass of :class:`~pgdcli.algorithms.runge_kutta.ExplicitRungeKutta` with its coefficients, for a
linearly implicit one of :class:`~pgdcli.algorithms.rosenbrock.Rosenbrock`) and one entry here; its
name is also one of the spec's choices (``pgdcli.problem.spec_options.INTEGRATORS``, in a layer that
does not import this one; a test keeps the two equal).

``auto`` is :data:`DEFAULT`'s explicit pair watching for stiffness: when its steps are held at its
stability limit the march starts again with :data:`STIFF` (:mod:`pgdcli.algorithms.stiffness`).
"""

from __future__ import annotations

from .bogacki_shampine import BogackiShampine32
from .dop853 import Dop853
from .rosenbrock import Rodas4
from .stepping import Stepper

__all__ = ["METHODS", "CHOICES", "AUTO", "DEFAULT", "STIFF", "stepper"]

#: ``solver.integrator`` -> the stepper's class.
METHODS: dict[str, type[Stepper]] = {
    "dop853": Dop853,
    "bs32": BogackiShampine32,
    "rodas4": Rodas4,
}

AUTO = "auto"
#: The choices of ``solver.integrator``.
CHOICES = (AUTO,) + tuple(METHODS)
DEFAULT = "dop853"
#: The stepper ``auto`` switches to on a stiff problem.
STIFF = "rodas4"


def stepper(name: str | None = None) -> Stepper:
    """The stepper named ``name`` (default :data:`DEFAULT`; ``auto``: it, watching for stiffness);
    ``KeyError`` names the choices."""
    key = DEFAULT if name is None else name
    if key == AUTO:
        method = METHODS[DEFAULT]()
        method.detect_stiffness = True
        return method
    if key not in METHODS:
        raise KeyError(f"unknown integrator {key!r}; expected one of {', '.join(CHOICES)}")
    return METHODS[key]()
