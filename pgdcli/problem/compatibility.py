"""Checks of a problem's data before any solve: finite initial values and coefficients, and
initial values that meet the Dirichlet boundary values at the start time.

Each is evaluated at the corners, the center and random points of its coordinates' box, and a
failure is one line naming the key. Where ``u(x, t0)`` and a condition ``u = g`` at an end of
``x`` disagree by ``d``, the solution jumps by ``d`` at that corner and has a layer of width
~ sqrt(t) there as time starts. No polynomial basis in t and x resolves it to a tolerance much
below ``d`` (measured on a user's combustion front, 0.5 (1 - tanh(10 (x - 0.3))) against u = 1
at x = 0, d = 2.5e-3: the method-of-lines reference's grids still disagreed by 1e-5 at 513
nodes), so such a problem is refused before solving instead of after minutes of refinement.
"""

from __future__ import annotations

import itertools

import numpy as np

from ..errors import SpecError

#: Random points (beside the corners) of the other coordinates where the two values are compared.
SAMPLES = 64


def _sample_points(problem, names: list[str], seed: int = 0) -> dict[str, np.ndarray]:
    """Corners (up to 2^6), the center and SAMPLES random points of the named coordinates."""
    if not names:
        return {}
    domains = [problem.coordinate(n).domain for n in names]
    # the corners and the center (a node of every odd Chebyshev count: 1/a on [-1, 1] is infinite there)
    corners = list(itertools.islice(itertools.product(*domains), 64)) + [tuple((lo + hi) / 2 for lo, hi in domains)]
    rng = np.random.default_rng(seed)
    random = [tuple(rng.uniform(lo, hi) for lo, hi in domains) for _ in range(SAMPLES)]
    points = np.array(corners + random, dtype=float).reshape(-1, len(names))
    return {n: points[:, i] for i, n in enumerate(names)}


LAYER = "which puts a layer at t = {t0:g} that no codebook resolves"


def check_initial_finite(problem) -> None:
    """Raise :class:`SpecError` where an initial value is not finite (``exp(1000*x)``, ``log(x - 2)``).

    Checked at the corners, the center and random points of its coordinates, before any
    solve: the solvers would otherwise stop inside a factorization with no word of the cause.
    """
    if problem.time is None:
        return
    for unknown in problem.unknowns:
        bad = _first_non_finite(problem, unknown.initial, unknown.initial.coordinates - {problem.time})
        if bad is not None:
            raise SpecError(f"{problem.source}: unknowns.{unknown.name}.initial is {bad[0]} at {bad[1]}: "
                            f"an initial value must be finite over the coordinates' domains")


def check_coefficients_finite(problem) -> None:
    """Raise :class:`SpecError` where an equation's coefficient is not finite (``-u/a`` with a = 0 in the box).

    Checked like the initial values (time included); the discretization would refuse it
    later, naming neither file nor equation.
    """
    for eq in problem.equations:
        for sep in eq.polynomial.terms.values():
            bad = _first_non_finite(problem, sep, sep.coordinates)
            if bad is not None:
                raise SpecError(f"{problem.source}: equations[{eq.index}]: the coefficient {sep} is {bad[0]} at "
                                f"{bad[1]}: coefficients must be finite over the coordinates' domains")


def _first_non_finite(problem, sep, coordinates) -> tuple[float, str] | None:
    """``(value, 'a=0, ...')`` at the first sample point where ``sep`` is not finite, else None."""
    names = sorted(coordinates)
    values = _sample_points(problem, names)
    size = len(next(iter(values.values()))) if values else 1
    with np.errstate(all="ignore"):
        v = np.broadcast_to(np.asarray(sep.evaluate(**values), dtype=float), (size,))
    bad = np.flatnonzero(~np.isfinite(v))
    if not bad.size:
        return None
    i = int(bad[0])
    return float(v[i]), ", ".join(f"{n}={values[n][i]:.6g}" for n in names) or "every point"


def check_initial_meets_boundary(problem, tolerance: float, relative_tolerance: float = 0.0, *,
                                 why: str = LAYER, error=SpecError) -> None:
    """Raise ``error`` where an initial value misses a Dirichlet value by more than the tolerance.

    Parameters
    ----------
    problem : pgdcli.problem.model.Problem
        A problem with a time coordinate and space coordinates (others pass).
    tolerance, relative_tolerance : float
        The gap allowed, ``tolerance + relative_tolerance |g|``: the codebook's error bound.
    why : str
        Why they must agree (formatted with ``t0``, the start time), for the message.
    error : type
        The exception raised.
    """
    if problem.time is None:
        return
    for unknown in problem.unknowns:
        for coord_name, ends in unknown.boundary.items():
            coord = problem.coordinate(coord_name)
            for side, end, condition in zip(("low", "high"), coord.domain, ends):
                if condition is None or condition.kind != "value":
                    continue
                gap = _gap(problem, unknown, coord_name, float(end), condition, tolerance, relative_tolerance)
                if gap is not None:
                    initial, boundary, allowed, where = gap
                    t0 = problem.coordinate(problem.time).domain[0]
                    raise error(
                        f"{problem.source}: unknowns.{unknown.name}.initial is {initial:.10g} at {coord_name}="
                        f"{float(end):g}{where} but unknowns.{unknown.name}.boundary.{coord_name}.{side} is "
                        f"{boundary:.10g}: they differ by {abs(initial - boundary):.2g}, more than {allowed:.2g}, "
                        f"{why.format(t0=t0)}; make the initial value meet the boundary value there")


def _gap(problem, unknown, coord_name, end, condition, tolerance, relative_tolerance):
    """``(initial, boundary, allowed, where)`` at the worst sample when they differ too much, else None."""
    others = sorted((unknown.initial.coordinates | condition.value.coordinates) - {coord_name, problem.time})
    values = _sample_points(problem, others)
    size = len(next(iter(values.values()))) if values else 1
    at_end = {**values, coord_name: np.full(size, end)}
    initial = np.broadcast_to(np.asarray(unknown.initial.evaluate(**at_end), dtype=float), (size,))
    boundary = np.broadcast_to(np.asarray(condition.value.evaluate(**at_end), dtype=float), (size,))
    with np.errstate(all="ignore"):
        gap = np.abs(initial - boundary)
    allowed = tolerance + relative_tolerance * np.abs(boundary)
    worst = int(np.argmax(gap - allowed))
    if not np.isfinite(gap[worst]) or gap[worst] <= allowed[worst]:
        return None
    where = "".join(f", {n}={values[n][worst]:.6g}" for n in others)
    return float(initial[worst]), float(boundary[worst]), float(allowed[worst]), where
