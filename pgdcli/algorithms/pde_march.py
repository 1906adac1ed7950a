"""Reaction-diffusion systems: the exponential march in time.

The system (:mod:`.pde_system`) is ``w_s' = L_s w_s + N_s(t, w)`` per species ``s`` on the grid
``(x, [y], parameters)``, ``L_s = sum_a c_sa(p) A_sa`` the diffusion. The diffusion is integrated
exactly (phi-functions of ``h L_s``); ``N`` is explicit. The operations on the state live in the
operators (:class:`.pde_operators.DenseOperators` on the whole grid as one array,
:class:`.pde_train.TrainOperators` on tensor trains); this module holds only the time stepping,
through their small interface (``phi``, ``apply``, ``nonlinear``, ``combine``, ``norm``, ``states``).

Two schemes:

* ``etdrk4`` (default): the exponential time differencing Runge-Kutta scheme of order 4 of Cox &
  Matthews (2002), its coefficients from :mod:`.pde_phi` (contour integral of Kassam & Trefethen on
  the eigenvalues). Its error constant involves derivatives of ``N`` along the solution only, so the
  diffusion's stiffness does not shrink its steps. ``N`` may depend on time: the stages are
  evaluated at ``t``, ``t + h/2``, ``t + h/2`` and ``t + h``.
* ``lawson4``: the integrating-factor (Lawson) Runge-Kutta scheme of order 4, kept for the
  comparison (``benchmarks/nonlinear_pde.py``): its error constant holds commutators of ``L`` with
  ``N``, large for stiff diffusion (Fisher: 1077 steps against ETDRK4's ~60).

Both with step doubling (Richardson: ``(half - whole) / 15``, the accepted state extrapolated),
the local error held in the RMS over the grid (and species) to ``LOCAL_FRACTION * tolerance * h / T``
per step, every rounding to ``ROUND_FRACTION * tolerance * h / T``. An advection ``u der(u, x)``
stays explicit: on Chebyshev nodes it bounds the steps by ~ 1 / (|u| n^2).

Output: the states ``u_s`` (full nodes, one tensor train per species) at given times, or
(``slab_nodes``) one slab per accepted step with the states at its Chebyshev-Lobatto nodes, the
inner ones by single steps of their size from the start of the step (sharing its first ``N``
evaluation).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..blas import one_blas_thread
from ..discretization.basis import chebyshev_unit_nodes
from ..errors import SolverError
from ..progress import MarchStep, emit
from .pde_operators import DenseOperators
from .pde_system import PdeSystem, compile_pde_system
from .pde_train import TrainOperators

__all__ = ["PdeSystem", "compile_pde_system", "march_pde", "PdeMarchResult", "SCHEMES", "UnderResolved",
           "DENSE_LIMIT"]

SAFETY = 0.8
LOCAL_FRACTION, ROUND_FRACTION = 0.3, 0.02
#: A step below this share of the time span ends the march.
MIN_STEP = 1e-9
SCHEMES = ("etdrk4", "lawson4")
#: Largest grid (values of all species) marched as a whole array instead of tensor trains.
DENSE_LIMIT = 2_000_000
#: With ``tail_limit``, the march stops once the Chebyshev tail of ``u`` along a space coordinate exceeds
#: this many times the tolerance: the codebook would fail the gate there anyway (its tail alone), and an
#: under-resolved steep front (Burgers at nu = 0.01 on 33 nodes) oscillates, which an explicit advection
#: answers with ever smaller steps (924 steps to t = 0.35, still shrinking, against 92 steps to t = 0.5 on
#: 129 nodes).
TAIL_ABORT = 10.0


class UnderResolved(SolverError):
    """The march stopped: space coordinate ``coordinate`` lacks nodes (its Chebyshev tail, ``tail``, at ``time``)."""

    def __init__(self, message: str, coordinate: str, time: float, tail: float) -> None:
        super().__init__(message)
        self.coordinate, self.time, self.tail = coordinate, time, tail


@dataclass
class PdeMarchResult:
    """States at ``times`` (each a list of tensor trains over the full nodes, one per species) and the counts."""

    times: np.ndarray
    states: list
    steps: int
    rejected: int
    max_rank: int
    breakpoints: np.ndarray | None = None
    step_sizes: list = field(default_factory=list)
    evaluations: int = 0


def _etdrk4(ops, w, t: float, h: float, delta: float, Nw=None):
    """One ETDRK4 step (Cox & Matthews) of ``w' = L w + N(t, w)``; ``Nw`` reuses ``N(t, w)``."""
    F = ops.phi(h)
    ap, nl, comb = ops.apply, ops.nonlinear, ops.combine
    Na = nl(w, t, delta / h) if Nw is None else Nw
    E2w = ap(F["E2"], w, delta)
    a = comb([E2w, ap(F["Q"], Na, delta)], [1.0, 1.0], delta)
    Nb = nl(a, t + h / 2, delta / h)
    b = comb([E2w, ap(F["Q"], Nb, delta)], [1.0, 1.0], delta)
    Nc = nl(b, t + h / 2, delta / h)
    c = comb([ap(F["E2"], a, delta), ap(F["Q"], comb([Nc, Na], [2.0, -1.0], delta / h), delta)], [1.0, 1.0], delta)
    Nd = nl(c, t + h, delta / h)
    parts = [ap(F["E"], w, delta), ap(F["b1"], Na, delta), ap(F["b23"], comb([Nb, Nc], [1.0, 1.0], delta / h), delta),
             ap(F["b4"], Nd, delta)]
    return comb(parts, [1.0] * 4, delta)


def _lawson4(ops, w, t: float, h: float, delta: float, Nw=None):
    """One integrating-factor (Lawson) RK4 step of ``w' = L w + N(t, w)``."""
    F = ops.phi(h)
    E, E2 = F["E"], F["E2"]
    ap, nl, comb = ops.apply, ops.nonlinear, ops.combine
    k1 = nl(w, t, delta / h) if Nw is None else Nw
    half_w = ap(E2, w, delta)
    k2 = nl(comb([half_w, ap(E2, k1, delta)], [1.0, h / 2], delta), t + h / 2, delta / h)
    k3 = nl(comb([half_w, k2], [1.0, h / 2], delta), t + h / 2, delta / h)
    full_w = ap(E2, half_w, delta)
    k4 = nl(comb([full_w, ap(E2, k3, delta)], [1.0, h], delta), t + h, delta / h)
    combo = comb([ap(E, k1, delta), ap(E2, comb([k2, k3], [1.0, 1.0], 0.0), delta), k4], [1.0, 2.0, 1.0], 0.0)
    return comb([full_w, combo], [1.0, h / 6], delta)


def _operators(system: PdeSystem, dense: bool | None):
    size = len(system.species) * float(np.prod(system.shape))
    if (size <= DENSE_LIMIT) if dense is None else dense:
        return DenseOperators(system)
    return TrainOperators(system)


def march_pde(system: PdeSystem, tolerance: float, times: np.ndarray | None = None, *, scheme: str = "etdrk4",
              slab_nodes: int | None = None, max_steps: int = 20000, callback=None,
              fixed_step: float | None = None, dense: bool | None = None,
              tail_limit: bool | list = False) -> PdeMarchResult:
    """March ``w`` with step doubling; the states ``u`` at ``times`` or at per-step slab nodes.

    Parameters
    ----------
    system : PdeSystem
    tolerance : float
        RMS target over the grid (see the module docstring).
    times : ndarray, optional
        Ascending output times in the span (the steps land on them).
    scheme : {'etdrk4', 'lawson4'}
    slab_nodes : int, optional
        Instead of ``times``: one slab per accepted step with this many Chebyshev-Lobatto nodes.
    fixed_step : float, optional
        Steps of this size (shortened to land on the output times), every one accepted: the scheme's
        order can be measured.
    dense : bool, optional
        March the whole grid as an array (default: when it has at most :data:`DENSE_LIMIT` values) or
        as tensor trains.
    tail_limit : bool or list of str
        Stop with :class:`UnderResolved` once the Chebyshev tail of ``u`` along a space coordinate (those
        named, or all with True) exceeds :data:`TAIL_ABORT` x ``tolerance`` (whole-grid march only).
    callback : callable, optional
        After every accepted step: a :class:`~pgdcli.progress.MarchStep`.
    """
    if scheme not in SCHEMES:
        raise SolverError(f"scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")
    # small dense products (SVD of the supercore, m x m products): one BLAS thread; threads competing
    # for the cores make each step many times slower on small trains (benchmarks/nonlinear_pde.py)
    watched = list(system.modes[:system.space]) if tail_limit is True else list(tail_limit or [])
    with one_blas_thread():
        return _march(system, tolerance, times, {"etdrk4": _etdrk4, "lawson4": _lawson4}[scheme], slab_nodes,
                      max_steps, callback, fixed_step, dense, watched)


def _march(system, tolerance, times, step, slab_nodes, max_steps, callback, fixed_step, dense,
           watched) -> PdeMarchResult:
    t0, t1 = system.t_span
    T = t1 - t0
    ops = _operators(system, dense)
    root = np.sqrt(ops.size)
    w, t, h = ops.initial(), t0, fixed_step or 1e-3 * T
    targets = np.asarray([t1] if times is None else times, dtype=float)
    theta = (chebyshev_unit_nodes(slab_nodes) + 1.0) / 2.0 if slab_nodes else None  # nodes on [0, 1]
    state_delta = ROUND_FRACTION * tolerance * root  # the stored states' rounding (dense: their TT-SVD)
    out_times, states = ([t0], [ops.states(w, state_delta)]) if slab_nodes else ([], [])
    steps, rejected, max_rank, sizes, anchor = 0, 0, ops.rank(w), [], None
    for target in targets:
        while t < target - 1e-14 * T:
            if steps + rejected > max_steps:
                raise SolverError(f"the PDE march took more than {max_steps} steps at t = {t:.6g}")
            if h < MIN_STEP * T:
                raise SolverError(f"the PDE march's step fell below {MIN_STEP:g} x the time span at t = {t:.6g} "
                                  f"(stiff explicit terms: an advection on many nodes?)")
            h = min(h, target - t)
            delta = ROUND_FRACTION * tolerance * h / T * root
            Nw = ops.nonlinear(w, t, delta / h)
            whole = step(ops, w, t, h, delta, Nw)
            half = step(ops, step(ops, w, t, h / 2, delta, Nw), t + h / 2, h / 2, delta)
            diff = ops.combine([half, whole], [1.0, -1.0], 0.0)
            err = ops.norm(diff) / 15.0 / root
            allowed = LOCAL_FRACTION * tolerance * h / T
            anchor, noise = _noise_limited(anchor, h, err / allowed)
            if noise and ops.tighten():
                continue  # the roundings' noise, not the step, set the estimate: the same step, rounded tighter
            if err <= allowed or fixed_step:
                if slab_nodes:
                    for th in theta[1:-1]:
                        states.append(ops.states(step(ops, w, t, th * h, delta, Nw), state_delta))
                        out_times.append(t + th * h)
                w = ops.combine([half, diff], [1.0, 1.0 / 15.0], delta)
                t += h
                steps += 1
                sizes.append(h)
                max_rank = max(max_rank, ops.rank(w))
                _watch(ops, system, w, t, tolerance, watched)
                if slab_nodes:
                    states.append(ops.states(w, state_delta))
                    out_times.append(t)
                emit(callback, MarchStep(t, t1, steps, [[max_rank]] * len(system.species), t0))  # ranks per unknown
            elif not np.isfinite(err):
                rejected += 1
                h *= 0.2
                continue
            else:
                rejected += 1
            h = fixed_step or h * min(2.0, max(0.2, SAFETY * (allowed / max(err, 1e-300)) ** 0.2))
        if not slab_nodes:
            states.append(ops.states(w, state_delta))
            out_times.append(t)
    max_rank = max(max_rank, max(max(s.ranks, default=1) for per in states for s in per))
    breakpoints = np.concatenate([[t0], np.cumsum(sizes) + t0]) if slab_nodes else None
    return PdeMarchResult(np.asarray(out_times), states, steps, rejected, max_rank, breakpoints, sizes,
                          ops.evaluations)


def _noise_limited(anchor, h: float, ratio: float) -> tuple:
    """``(new anchor, noise)``: did the error estimate fall with the step since the anchor ``(h, err / allowed)``?

    The step-doubling estimate of a step's error falls like ``h^5`` and what is allowed like ``h``: a
    step 30% shorter than the anchor's should cut their ratio 4-fold. When it falls less than half as
    much while still a tenth of the allowed or more, it is the noise of the roundings (trains only: the
    whole grid is not rounded), which falls with ``h`` as fast as the allowed error. The anchor moves to
    each attempt 30% shorter than it, or longer.
    """
    if anchor is None or h > anchor[0]:
        return (h, ratio), False
    if h >= 0.7 * anchor[0]:
        return anchor, False
    h0, ratio0 = anchor
    return (h, ratio), ratio >= 0.1 and ratio > 2.0 * ratio0 * (h / h0) ** 4


def _watch(ops, system, w, t: float, tolerance: float, watched: list) -> None:
    """Raise :class:`UnderResolved` when ``u``'s Chebyshev tail along a watched space axis passes the limit."""
    if not watched:
        return
    axis, tail = ops.tail(w, [system.modes.index(x) for x in watched])
    if tail > TAIL_ABORT * tolerance:
        x = system.modes[axis]
        raise UnderResolved(f"{x} lacks nodes: the Chebyshev tail of the solution along it reached {tail:.2g} "
                            f"({tail / tolerance:.3g} x the tolerance) at t = {t:.6g} on {system.shape[axis]} nodes",
                            x, t, tail)
