"""The outcome of :func:`pgdcli.checks.verify.verify`: per-unknown errors, failures, the gate.

:class:`VerifyReport` holds what a check measured and decides whether it passed
(``pgd verify``'s exit status and its JSON report, the keys in docs/verify.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from .compare import UnknownErrors

__all__ = ["Failure", "VerifyReport"]


@dataclass
class Failure:
    """A parameter point where the reference integration failed."""

    point: dict[str, float]
    message: str

    def to_dict(self) -> dict:
        return {"point": {k: float(v) for k, v in self.point.items()}, "message": self.message}


@dataclass
class VerifyReport:
    """Outcome of :func:`verify`.

    Attributes
    ----------
    codebook : str or None
        Path of the codebook file (None for an in-memory codebook).
    problem : str
        Problem name.
    time : str or None
        Name of the time coordinate (None: a steady problem).
    coordinates : list of str
        All coordinates, codebook order.
    unknowns : dict of str to UnknownErrors
    failures : list of Failure
    settings : dict
        Sampling and integration settings (the JSON ``settings`` object).
    max_error, max_rel_error : float or None
        The gate given to :func:`verify` (used by :meth:`to_dict`); without either, the gate is the
        codebook's own tolerance.
    tolerance, relative_tolerance : float or None, float
        The codebook's tolerance (``solver.tolerance`` and ``solver.relative_tolerance`` of its spec;
        None when the codebook records none).
    samples : dict of str to ndarray, shape (S,)
        The parameter points.
    times : ndarray, shape (T,)
        The times (sorted; empty for a steady problem).
    reference, codebook_values : dict of str to ndarray, shape (S, T)
        Reference (NaN at failed points) and codebook values; with space
        coordinates shape (S, T, X_1, ..., X_d) on the tensor grid of
        ``space_points``, and (S, X_1, ..., X_d) for a steady problem.
    wall_time : float
        Seconds.
    space_points : dict of str to ndarray
        With space coordinates: the points of each (sorted); else empty.
    events : dict of str to pgdcli.checks.events.EventCheck
        The codebook's event times against scipy's event location at the same parameter points
        (empty for a codebook without events); held to the codebook's tolerance.
    """

    codebook: str | None
    problem: str
    time: str | None
    coordinates: list[str]
    unknowns: dict[str, UnknownErrors]
    failures: list[Failure]
    settings: dict
    max_error: float | None = None
    max_rel_error: float | None = None
    samples: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    times: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    reference: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    codebook_values: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    wall_time: float = 0.0
    space_points: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    tolerance: float | None = None
    relative_tolerance: float = 0.0
    events: dict = field(default_factory=dict, repr=False)

    @property
    def n_points(self) -> int:
        """Parameter points checked (including failed ones)."""
        return int(self.settings.get("parameter_points", 0))

    @property
    def not_checked(self) -> int:
        """Parameter points the time budget left unchecked (0: the report is complete)."""
        return int(self.settings.get("not_checked", 0))

    def tolerance_gate(self, max_error: float | None = None, max_rel_error: float | None = None) -> bool:
        """True when the gate is the codebook's own tolerance: no threshold given, and the codebook has one."""
        return max_error is None and max_rel_error is None and self.tolerance is not None

    def gate_text(self, max_error: float | None = None, max_rel_error: float | None = None) -> str:
        """The gate in words, e.g. ``every reference integration succeeds, max abs error <= 1e-08``."""
        gates = ["every reference integration succeeds"]
        if max_error is not None:
            gates.append(f"max abs error <= {max_error:.3g}")
        if max_rel_error is not None:
            gates.append(f"max rel error <= {max_rel_error:.3g}")
        if self.tolerance_gate(max_error, max_rel_error):
            relative = f" + {self.relative_tolerance:.3g} |u|" if self.relative_tolerance else ""
            gates.append(f"error <= the codebook's tolerance {self.tolerance:.3g}{relative}")
        return ", ".join(gates)

    def violations(self, max_error: float | None = None, max_rel_error: float | None = None) -> list[str]:
        """Reasons the check fails (empty when it passes), one line each.

        Parameters
        ----------
        max_error, max_rel_error : float, optional
            Thresholds of every unknown's max abs and max rel error. Without either, the gate is
            the codebook's own tolerance (when it records one).

        Returns
        -------
        list of str
        """
        reasons = []
        if self.not_checked:
            reasons.append(f"stopped at the time budget of {self.settings.get('max_seconds', 0):g} s with "
                           f"{self.not_checked} of {self.n_points} parameter point(s) not checked "
                           f"(raise --max-seconds)")
        if self.failures:
            first = self.failures[0]
            reasons.append(
                f"the reference integration failed at {len(self.failures)} of {self.n_points} parameter point(s)"
                f" (first: {_format_point(first.point)}: {first.message})"
            )
        for name, stats in self.unknowns.items():
            if max_error is not None and not stats.max_abs_error <= max_error:
                reasons.append(f"{name}: max abs error {stats.max_abs_error:.3e} > {max_error:.3e}"
                               f" at {_format_point(stats.where)}")
            if max_rel_error is not None and not stats.max_rel_error <= max_rel_error:
                reasons.append(f"{name}: max rel error {stats.max_rel_error:.3e} > {max_rel_error:.3e}"
                               f" at {_format_point(stats.where)}")
            if self.tolerance_gate(max_error, max_rel_error) and not stats.tolerance_ratio <= 1:
                reasons.append(f"{name}: max abs error {stats.max_abs_error:.3e} at {_format_point(stats.where)}, "
                               f"{stats.tolerance_ratio:.3g} x the codebook's tolerance {self.tolerance:.3g}")
        for name, check in self.events.items():
            if not check.accurate:
                reasons.append(f"event {name}: time error {check.error:.3e} at {_format_point(check.where)}, "
                               f"{check.ratio:.3g} x the codebook's tolerance (in time, or in the state for a slow "
                               f"crossing)")
        return reasons

    def passed(self, max_error: float | None = None, max_rel_error: float | None = None) -> bool:
        """True when every reference integration succeeded and the gate holds.

        Without either threshold, the gate is the codebook's own tolerance: every unknown's
        ``tolerance_ratio`` at most 1.

        Parameters
        ----------
        max_error : float, optional
            Largest allowed absolute error of every unknown.
        max_rel_error : float, optional
            Largest allowed relative error (``max_abs_error / reference_scale``).

        Returns
        -------
        bool
        """
        return not self.violations(max_error, max_rel_error)

    def to_dict(self) -> dict:
        """The JSON report (``pgd verify --format json``); keys in docs/verify.md."""
        return {
            "codebook": self.codebook,
            "problem": self.problem,
            "passed": self.passed(self.max_error, self.max_rel_error),
            "gate": {"max_error": self.max_error, "max_rel_error": self.max_rel_error,
                     **({"tolerance": self.tolerance, "relative_tolerance": self.relative_tolerance}
                        if self.tolerance_gate(self.max_error, self.max_rel_error)
                        else {"tolerance": None, "relative_tolerance": None})},
            "settings": dict(self.settings),
            "unknowns": {name: stats.to_dict() for name, stats in self.unknowns.items()},
            "failures": {"count": len(self.failures), "points": [f.to_dict() for f in self.failures]},
            "complete": self.not_checked == 0,
            **({"events": {n: {"max_abs_error": _finite(c.error), "tolerance_ratio": _finite(c.ratio),
                               "where": dict(c.where), "points": c.points, "failed": c.failed}
                           for n, c in self.events.items()}} if self.events else {}),
            "wall_time": float(self.wall_time),
        }


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _format_point(point: Mapping[str, float]) -> str:
    return ", ".join(f"{k}={float(v):.6g}" for k, v in point.items()) or "(no parameters)"
