"""Progress of a solve: one typed event per thing worth telling, whatever the phase or the method.

:func:`pgdcli.solve` calls its ``callback`` with these events (as scipy's ``minimize`` passes an
``intermediate_result``): the solver's own steps (:class:`EnrichmentStep`, :class:`MarchStep`,
:class:`CrossSweep`), the error gate's reference solves (:class:`ReferenceProgress`), and the start of
every phase (:class:`PhaseStarted`: a solve at a node set, the gate, a refinement). Every event says
which phase it belongs to, how far that phase is (:meth:`ProgressEvent.fraction`, 0 to 1, or None)
and what it did in a few words (:meth:`ProgressEvent.describe`), so a display needs no branch per method.

A leaf of the package: every layer may import it, it imports nothing of the package.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import ClassVar

__all__ = ["ProgressEvent", "PhaseStarted", "EnrichmentStep", "AmenSweep", "MarchStep", "CrossSweep",
           "ReferenceProgress", "emit"]


@dataclass(frozen=True)
class ProgressEvent:
    """Base of the events; ``event["name"]`` reads a field as ``event.name`` does (callbacks written for dicts)."""

    #: The phase the event belongs to: ``"solve"``, ``"check"`` or ``"refine"``.
    phase: ClassVar[str] = "solve"
    #: Legacy item names of a field (``{"cross": "sweep"}``): the keys of the dicts these events replace.
    aliases: ClassVar[dict] = {}

    def fraction(self) -> float | None:
        """How far the phase is, from 0 to 1 (None: no measure of it)."""
        return None

    def describe(self) -> str:
        """A few words on what was done, for a progress line."""
        return ""

    def __getitem__(self, key: str):
        name = self.aliases.get(key, key)
        if name not in {f.name for f in fields(self)}:
            raise KeyError(key)
        return getattr(self, name)

    def __contains__(self, key: str) -> bool:
        return self.aliases.get(key, key) in {f.name for f in fields(self)}


@dataclass(frozen=True)
class PhaseStarted(ProgressEvent):
    """A phase begins: ``what`` says which (``"solve"``, ``"check"``, ``"refine"``) and ``text`` how.

    Attributes
    ----------
    what : str
    text : str
        E.g. ``"march to RMS 7e-10 on t: 8, a: 20"``, ``"error against scipy at 243 check points"``.
    round : int
        The solve this phase belongs to, from 1.
    """

    what: str
    text: str
    round: int = 1

    @property
    def phase(self) -> str:  # type: ignore[override]
        return self.what

    def fraction(self) -> float | None:
        return 0.0

    def describe(self) -> str:
        return self.text


@dataclass(frozen=True)
class EnrichmentStep(ProgressEvent):
    """One more term of the PGD enrichment.

    Attributes
    ----------
    mode : int
        Terms so far.
    residual : float
        Relative residual after it.
    iterations : int
        Fixed-point iterations the term took.
    target : float
        The relative residual asked.
    max_modes : int
    """

    mode: int
    residual: float
    iterations: int
    target: float = float("nan")
    max_modes: int = 0

    def fraction(self) -> float | None:
        return _decades(self.residual, self.target)

    def describe(self) -> str:
        of = f"/{self.max_modes}" if self.max_modes else ""
        return f"{self.mode}{of} modes, residual {self.residual:.2e} (target {self.target:.0e})"


@dataclass(frozen=True)
class AmenSweep(ProgressEvent):
    """A sweep of the tensor-train solver (AMEn) of a linear problem.

    Attributes
    ----------
    sweep : int
    residual : float
        The 2-norm at the nodes of the integrated equations' residual (absolute).
    target : float
        The residual asked: the solver's own target, not the tolerance.
    ranks : list of int
    """

    sweep: int
    residual: float
    target: float
    ranks: list

    def fraction(self) -> float | None:
        return _decades(self.residual, self.target) if self.residual < 1.0 else 0.0

    def describe(self) -> str:
        return (f"tensor-train sweep {self.sweep}: residual {self.residual:.2e} (its target {self.target:.0e}), "
                f"max rank {max(self.ranks, default=1)}")


@dataclass(frozen=True)
class MarchStep(ProgressEvent):
    """An accepted step of a time march.

    Attributes
    ----------
    time, end : float
        Time reached and end of the time domain.
    steps : int
        Accepted steps so far.
    ranks : list of tuple of int
        Per unknown, the tensor-train ranks of the state (empty for a march of the grid's array).
    start : float
        Start of the time domain.
    """

    time: float
    end: float
    steps: int
    ranks: list
    start: float = 0.0

    def fraction(self) -> float | None:
        span = self.end - self.start
        return min(1.0, max(0.0, (self.time - self.start) / span)) if span > 0 else None

    def describe(self) -> str:
        ranks = [r for per_unknown in self.ranks for r in per_unknown]
        rank = f", max rank {max(ranks)}" if ranks else ""
        return f"t = {self.time:.4g}/{self.end:.4g}, {self.steps} steps{rank}"


@dataclass(frozen=True)
class CrossSweep(ProgressEvent):
    """A half sweep of the cross of trajectories.

    Attributes
    ----------
    sweep : int
    residual : float
        The difference between the last two interpolants (relative).
    target : float
    trajectories : int
        Trajectories integrated so far.
    ranks : list of int
    """

    sweep: int
    residual: float
    target: float
    trajectories: int
    ranks: list
    aliases: ClassVar[dict] = {"cross": "sweep"}

    def fraction(self) -> float | None:
        return _decades(self.residual, self.target)

    def describe(self) -> str:
        return (f"cross sweep {self.sweep}: {self.trajectories:,} trajectories, difference {self.residual:.2e} "
                f"(target {self.target:.0e}), max rank {max(self.ranks, default=0)}")


@dataclass(frozen=True)
class ReferenceProgress(ProgressEvent):
    """The error gate's independent reference: how much of it is integrated.

    Attributes
    ----------
    done, total : float
        Parameter points integrated of all (``unit`` "points"), or the time reached of the
        time domain (``unit`` "time", one vectorized integration of every point).
    unit : str
    """

    done: float
    total: float
    unit: str = "points"
    phase: ClassVar[str] = "check"

    def fraction(self) -> float | None:
        return min(1.0, max(0.0, self.done / self.total)) if self.total > 0 else None

    def describe(self) -> str:
        if self.unit == "time":
            return f"reference at {100 * (self.fraction() or 0.0):.0f}% of the time domain"
        return f"reference at {int(self.done)}/{int(self.total)} parameter points"


def _decades(residual: float, target: float) -> float | None:
    """Decades of a residual reached over those asked (from 1), within [0, 1]."""
    if not (0.0 < target < 1.0) or not math.isfinite(residual):
        return None
    if residual <= 0.0:
        return 1.0
    return min(1.0, max(0.0, math.log10(residual) / math.log10(target)))


def emit(callback, event: ProgressEvent) -> None:
    """Hand ``event`` to ``callback`` unless it is None."""
    if callback is not None:
        callback(event)
