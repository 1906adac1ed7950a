"""The result of :func:`pgdcli.solve`, whatever the method: codebook, status, message, convergence history."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .outcome import Status

__all__ = ["SolveResult", "Status"]


@dataclass
class SolveResult:
    """Outcome of :func:`solve`.

    Attributes
    ----------
    codebook : pgdcli.codebook.codebook.Codebook
    converged : bool
        True when the solver converged and the measured error meets the tolerance.
    status : Status
        An ``IntEnum``: 0 converged, 1 ``max_modes`` reached, 2 stagnated, 3 the march failed,
        4 the measured error exceeds the tolerance.
    message : str
    residuals : ndarray, shape (n_modes + 1,)
        Relative residual before the first mode and after each enrichment.
    iterations : ndarray, shape (n_modes,)
        Fixed-point iterations of each enrichment.
    wall_time : float
        Seconds.
    warnings : list of str
        Findings that do not stop the solve, e.g. a reference that could not
        check the codebook.
    check : pgdcli.checks.check.CheckResult or None
        The error measured against the independent reference (None when the
        solver did not converge).
    accurate : bool or None
        The measured error meets the tolerance (None: it could not be measured).
    """

    codebook: object
    converged: bool
    status: Status
    message: str
    residuals: np.ndarray
    iterations: np.ndarray
    wall_time: float
    warnings: list = field(default_factory=list)
    check: object = None  # pgdcli.checks.check.CheckResult (checks sit above the algorithms)
    accurate: bool | None = None

    @property
    def residual(self) -> float:
        return float(self.residuals[-1])

    @property
    def n_modes(self) -> int:
        return int(self.iterations.size)
