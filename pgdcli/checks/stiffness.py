"""Which method integrates the ODE reference: an explicit one, or an implicit one where the problem is stiff.

The reference of the error gate and of ``pgd verify`` is scipy's DOP853 at a tight tolerance. On a
stiff problem (a decay rate far faster than the solution varies) an explicit method is held to steps
of ``h |lambda| <~`` its stability limit over the whole time domain, however smooth the solution: the
reference crawls, or spends its evaluation budget and falls back to integrating node to node.
:func:`estimate_stiffness` decides before integrating, from cheap quantities at the sample:

* the fastest decay rate ``max(-Re lambda)`` of the right-hand side's Jacobian (exact:
  :func:`~pgdcli.checks.reference_system.reference_jacobian`; finite differences where a function
  cannot be differentiated) at the initial states and at :data:`PROBES` states along the way, which
  gives the explicit method's stability-limited steps ``span * rate / EXPLICIT_LIMIT`` (a purely
  imaginary eigenvalue is an oscillation the steps must follow anyway: it does not count);
* the rate at which the solution varies once the fast transients have died out (``|du/dt| / max |u|``
  per unknown, from differences between up to :data:`RATE_PROBES` states along the way), which gives
  the steps accuracy needs, :data:`STEPS_PER_RADIAN` per unit of rate and time at the reference's
  tolerance.

The problem is stiff when the stability-limited steps exceed :data:`MIN_STEPS` and :data:`RATIO`
times the accuracy steps; the reference then integrates with Radau (an A-stable implicit method,
steps set by accuracy alone). The states along the way are the codebook's: the choice needs them only
roughly, and it never changes a verdict, only the time the reference takes: both methods run at
tolerances orders of magnitude tighter than any the check compares with.

:func:`decide_stiffness` is the one decision of the error gate (:mod:`pgdcli.checks.check`) and of
``pgd verify`` (:mod:`pgdcli.checks.verify`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .compare import codebook_at_samples
from .reference_system import CompiledSystem, reference_jacobian

__all__ = ["Stiffness", "decide_stiffness", "estimate_stiffness", "forced", "not_estimated", "probe_times",
           "EXPLICIT_LIMIT", "STEPS_PER_RADIAN", "RATIO", "MIN_STEPS", "PROBES", "RATE_PROBES", "STIFF_METHOD",
           "STIFF_RTOL", "STIFF_ATOL", "STIFF_SHARE", "stiff_tolerances", "solution_scale"]

#: The stiff reference (``check_codebook(stiff=True)``): Radau IIA of order 5, at these tolerances at the
#: tightest (:func:`stiff_tolerances`).
STIFF_METHOD, STIFF_RTOL, STIFF_ATOL = "Radau", 1e-12, 1e-14
#: The stiff reference is asked for this share of the promise, as the nonlinear method of lines is: its error
#: then moves a verdict only for a codebook within a few thousandths of its tolerance.
STIFF_SHARE = 1e-4


def stiff_tolerances(tolerance: float, relative_tolerance: float, scale: float) -> tuple[float, float]:
    """Radau's ``(rtol, atol)`` for a promise ``|u - u_ref| <= tolerance + relative_tolerance |u_ref|``:
    :data:`STIFF_SHARE` of it, no tighter than :data:`STIFF_RTOL`, :data:`STIFF_ATOL`.

    Radau controls ``atol + rtol |u|``: its ``atol`` is the share of ``tolerance``, its ``rtol`` the share of
    ``relative_tolerance`` or, for an absolute promise, of ``tolerance / scale`` (``scale``: the solution's
    size, a power of ten at least 1, so that the reference and its cache do not depend on the codebook's
    last digits).
    """
    relative = max(relative_tolerance, tolerance / max(1.0, scale))
    return max(STIFF_RTOL, STIFF_SHARE * relative), max(STIFF_ATOL, STIFF_SHARE * tolerance)


def solution_scale(values: dict) -> float:
    """The power of ten at or above the largest finite ``|value|`` (at least 1)."""
    largest = max((float(np.max(np.abs(v[np.isfinite(v)]), initial=0.0)) for v in values.values()), default=0.0)
    return float(10.0 ** np.ceil(np.log10(max(1.0, largest))))


#: DOP853's step times the decay rate it is held to (its stability region reaches about 6 on the negative
#: real axis; at the reference's tolerances scipy's step control holds it well below, so that this
#: underestimates its steps: the choice leans to DOP853).
EXPLICIT_LIMIT = 3.3
#: DOP853's steps per unit of ``rate * time`` (per radian of an oscillation) at rtol = atol = 1e-13,
#: measured on sines and harmonic oscillators (5 to 7); it scales as ``rtol^(-1/8)``.
STEPS_PER_RADIAN, STEPS_RTOL = 7.0, 1e-13
#: Stability-limited steps over accuracy steps above which the explicit reference is the slower
#: (``benchmarks/stiff_gate.py`` measures both on the same samples).
RATIO = 8.0
#: Below this many stability-limited steps DOP853 is quick whatever the ratio.
MIN_STEPS = 1000.0
#: States along the way where the Jacobian is taken (besides the initial ones), and between which the
#: solution's rate is measured (at most: a codebook's time nodes resolve its solution, a subset of
#: this many still follows an oscillation of as many periods as a tenth of them).
PROBES, RATE_PROBES = 8, 256
#: A transient of decay rate ``r`` is over (``exp(-TRANSIENT)`` of its size) after ``TRANSIENT / r``.
TRANSIENT = 40.0


@dataclass(frozen=True)
class Stiffness:
    """The estimate and the decision of :func:`estimate_stiffness`.

    Attributes
    ----------
    stiff : bool
        Integrate the reference with an implicit method.
    decay_rate : float
        Largest ``max(-Re lambda)`` of the Jacobian over the probed states (0 if none decays).
    solution_rate : float
        Largest ``|u'| / max |u|`` over the unknowns, samples and probed times past the transients.
    span : float
        Length of the time domain.
    stability_steps, accuracy_steps : float
        The explicit method's steps as its stability limits them, and as accuracy needs them.
    reason : str
        Why, when the decision was not estimated (:func:`forced`, :func:`not_estimated`).
    """

    stiff: bool
    decay_rate: float
    solution_rate: float
    span: float
    stability_steps: float
    accuracy_steps: float
    reason: str = ""

    def text(self) -> str:
        """Why the method was chosen, for the check's description ("" when it was given without a reason)."""
        if not np.isfinite(self.stability_steps):
            return self.reason
        verdict = "stiff" if self.stiff else "not stiff"
        return (f"{verdict}: an explicit method needs ~{self.stability_steps:.2g} steps for stability (decay "
                f"rate {self.decay_rate:.3g} over a time domain of {self.span:.3g}), ~{self.accuracy_steps:.2g} for "
                f"accuracy")


def forced(stiff: bool, reason: str = "") -> Stiffness:
    """A decision made without the estimate (``reason`` says why, for the check's description)."""
    nan = float("nan")
    return Stiffness(bool(stiff), nan, nan, nan, nan, nan, reason)


def not_estimated(reason: str) -> Stiffness:
    """The decision when no estimate can be made: not stiff (the explicit reference)."""
    return forced(False, f"stiffness not estimated: {reason}")


def probe_times(times: np.ndarray) -> np.ndarray:
    """The few of ``times`` (increasing) that :func:`estimate_stiffness` looks at: the first, the last and
    up to :data:`RATE_PROBES` spread between."""
    times = np.asarray(times, dtype=float)
    return times[_spread(times.size, RATE_PROBES + 1)]


def decide_stiffness(problem, codebook, points: Mapping[str, np.ndarray], S: int, times: np.ndarray,
                     rtol: float = STEPS_RTOL) -> Stiffness:
    """Whether the reference of ``codebook`` at these samples and times integrates with an implicit method.

    Stiff when the codebook's report says a stiff stepper marched it (``stiff``); else
    :func:`estimate_stiffness` along the codebook's states at a few of ``times``
    (:func:`probe_times`). ``rtol`` is the explicit reference's.
    """
    if codebook.report.get("stiff", 0):
        return forced(True, "the codebook was marched by a stiff stepper")
    probes = probe_times(times)
    states = codebook_at_samples(codebook, points, problem.time, probes, list(problem.unknown_names))
    return estimate_stiffness(problem, points, S, probes, states, rtol=rtol)


def estimate_stiffness(problem, points: Mapping[str, np.ndarray], S: int, times: np.ndarray,
                       states: Mapping[str, np.ndarray], *, rtol: float = STEPS_RTOL) -> Stiffness:
    """Whether the reference at these samples should integrate with an implicit method.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        With a time coordinate and no space coordinates.
    points : dict of str to ndarray, shape (S,)
        The parameter samples.
    S : int
    times : ndarray, shape (T,)
        Increasing, from the start of the time domain.
    states : dict of str to ndarray, shape (S, T)
        Per unknown, approximate values at the samples and times (a codebook's).
    rtol : float
        Tolerance of the explicit reference (the accuracy steps grow as ``rtol^(-1/8)``).

    Returns
    -------
    Stiffness
        :func:`not_estimated` (not stiff) when the states or the right-hand side are not finite.
    """
    times = np.asarray(times, dtype=float)
    t0, t1 = map(float, problem.time_coordinate.domain)
    with np.errstate(all="ignore"):
        system = CompiledSystem(problem, points, S, max_evaluations=np.iinfo(np.int64).max)
        Y = np.stack([np.asarray(states[u], dtype=float) for u in problem.unknown_names], axis=1)  # (S, q, T)
        if times[0] == t0:
            Y[:, :, 0] = system.initial(problem, points)
        if system.bad.any():
            return not_estimated(system.bad_reason)
        if not np.isfinite(Y).all():
            return not_estimated("the states are not finite")
        try:
            rate = _decay_rates(system, times, Y)  # (S,)
            slow = _solution_rate(times, Y, rate)
        except (np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError, OverflowError) as exc:
            return not_estimated(" ".join(str(exc).split()) or type(exc).__name__)
    if not (np.isfinite(rate).all() and np.isfinite(slow)):
        return not_estimated("the right-hand side or its Jacobian is not finite")
    span = t1 - t0
    fastest = float(rate.max(initial=0.0))
    stability = span * fastest / EXPLICIT_LIMIT
    accuracy = STEPS_PER_RADIAN * (rtol / STEPS_RTOL) ** (-1.0 / 8.0) * span * slow
    stiff = stability > MIN_STEPS and stability > RATIO * accuracy
    return Stiffness(bool(stiff), fastest, float(slow), span, float(stability), float(accuracy))


def _spread(T: int, count: int) -> np.ndarray:
    """``count`` indices (at most) spread evenly over range(T), the first and the last included."""
    return np.unique(np.round(np.linspace(0, T - 1, min(T, count))).astype(int))


def _decay_rates(system: CompiledSystem, times: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Per sample, the largest ``max(-Re lambda)`` of the Jacobian at the probed times (S,)."""
    rates = np.zeros(system.S)
    for j in _spread(times.size, PROBES + 1):
        J = reference_jacobian(system, float(times[j]), Y[:, :, j])
        values = np.linalg.eigvals(np.where(np.isfinite(J), J, 0.0))
        decay = np.where(np.isfinite(J).all(axis=(1, 2)), -values.real.min(axis=1), np.nan)
        rates = np.fmax(rates, decay)
    return np.maximum(rates, 0.0)


def _solution_rate(times: np.ndarray, Y: np.ndarray, rate: np.ndarray) -> float:
    """The largest ``|u(t_k+1) - u(t_k)| / (t_k+1 - t_k) / max |u|`` over unknowns, samples and intervals
    between probed times that start after their sample's transient: ``TRANSIENT / rate`` after the start,
    at most a quarter of the time domain (a transient that slow holds an explicit method to few steps).

    Differences of the states, not the right-hand side at them: states off the solution (a codebook
    not yet accurate) would make ``|u'|`` as large as the decay rate times their error.
    """
    scale = np.max(np.abs(Y), axis=(0, 2))  # (q,)
    scale = np.where(scale > 0, scale, 1.0)
    transient = np.minimum(TRANSIENT / np.where(rate > 0, rate, np.inf), 0.25 * (times[-1] - times[0]))
    steps = np.diff(times)
    slopes = np.abs(np.diff(Y, axis=2)) / np.where(steps > 0, steps, np.inf) / scale[None, :, None]  # (S, q, T-1)
    late = times[None, :-1] >= times[0] + transient[:, None]  # (S, T-1)
    return float(np.max(np.where(late[:, None, :], slopes, 0.0), initial=0.0))
