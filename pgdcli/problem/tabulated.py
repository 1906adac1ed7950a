"""An initial value given by a function of the parameters rather than by an expression.

The phases of a motion that an event resets (a bounce) start from the state after the reset, a
function of the parameters computed from the previous phase's codebook, not a formula of the
spec. :class:`TabulatedInitial` is that value in the interface of an initial
:class:`~pgdcli.problem.separable.Separable`: no separated terms, one joint part
(:class:`TabulatedJoint`) whose joint function is a Python callable of the parameters, which the
solvers separate on their nodes as they separate any joint coefficient and the references evaluate
directly. numpy only.
"""

from __future__ import annotations

from typing import Callable, Mapping, Sequence

import numpy as np

from .terms import SepTerm

__all__ = ["TabulatedFunction", "TabulatedJoint", "TabulatedInitial"]


class TabulatedFunction:
    """``function(values) -> ndarray``: a joint function of the coordinates ``names``, with a text.

    ``function`` receives a mapping of every name in ``names`` to broadcast arrays and returns their
    broadcast shape's values.
    """

    def __init__(self, function: Callable[[Mapping[str, np.ndarray]], np.ndarray], names: Sequence[str], text: str):
        self.function, self.names, self.text = function, tuple(names), text

    def __call__(self, values: Mapping[str, np.ndarray]) -> np.ndarray:
        arrays = np.broadcast_arrays(*[np.asarray(values[n], dtype=float) for n in self.names])
        shape = arrays[0].shape
        out = self.function({n: a.reshape(-1) for n, a in zip(self.names, arrays)})
        return np.asarray(out, dtype=float).reshape(shape)


class TabulatedJoint:
    """``term * tree(values)``: the joint part of :class:`TabulatedInitial` (a Joint's interface)."""

    def __init__(self, term: SepTerm, tree: TabulatedFunction):
        self.term, self.tree = term, tree

    @property
    def tree_coordinates(self) -> frozenset[str]:
        return frozenset(self.tree.names)

    @property
    def coordinates(self) -> frozenset[str]:
        return self.term.coordinates | self.tree_coordinates

    def evaluate(self, /, **values: np.ndarray) -> np.ndarray:
        return self.term.evaluate(**values) * self.evaluate_tree(values)

    def evaluate_tree(self, values: Mapping[str, np.ndarray]) -> np.ndarray:
        return self.tree(values)

    def function_text(self) -> str:
        return self.tree.text

    def __str__(self) -> str:
        return self.tree.text


class TabulatedInitial:
    """An initial value ``function(parameters)``, in the interface of an initial Separable."""

    terms: tuple = ()

    def __init__(self, function: TabulatedFunction):
        self.joints = (TabulatedJoint(SepTerm(1.0), function),)

    @property
    def coordinates(self) -> frozenset[str]:
        return self.joints[0].coordinates

    def evaluate(self, /, **values: np.ndarray) -> np.ndarray:
        given = {n: values[n] for n in self.joints[0].tree.names}
        shape = np.broadcast_shapes(*(np.shape(v) for v in values.values())) if values else ()
        return np.broadcast_to(self.joints[0].evaluate(**given), shape)

    def constant_value(self) -> float | None:
        return None

    def __str__(self) -> str:
        return self.joints[0].function_text()
