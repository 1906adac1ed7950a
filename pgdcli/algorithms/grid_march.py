"""Small parameter grids: the time march on the whole array of grid values, compressed once.

On a grid of a few thousand to a few hundred thousand nodes (three initial conditions
with 20-40 nodes each, six with 8) every separated operation of the tensor-train march
(:mod:`pgdcli.algorithms.march`: roundings, QR, crosses) costs more than the
whole array does: one right-hand side on the array is a few elementwise products.
There the state is kept as the array of its values at all grid nodes, advanced by
the same DOP853 pair and step control, stored at the same time nodes, and the
space-time array of each unknown is compressed once by TT-SVD (measured randomized ranges,
:mod:`pgdcli.tensors.tt_svd`) to the same share of the tolerance as the train march's
space-time rounding; a long march by runs of at most :data:`CHUNK_FLOATS` floats, joined at
the end. The codebook is the same kind (one tensor train per unknown, time first); the cost
is about that of one vectorized ``solve_ivp`` over the grid plus the TT-SVD
(benchmarks/build_speed.py).

The error control is the train march's: the embedded estimate of each unknown in the
root-mean-square norm over the grid nodes may be ``LOCAL_FRACTION * tolerance * h / span``
(the local errors add up to that share of the tolerance); the user's tolerance, a max abs
error, is enforced by the error gate after the march (``pgdcli.driver._checked_march``).

:data:`GRID_LIMIT` decides which march a problem gets (:func:`fits_grid`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import DOP853

from ..errors import SolverError
from ..tensors.tt_svd import tt_from_full_sketched
from ..tensors.tt import TT
from .blowup import BlowupWatch
from .dop853_stepper import dense_weights
from .general_rhs import underflow_hint
from .polynomial_rhs import SINGLE_POINT, NonlinearSystem
from .space_time import join_and_round
from .step_control import LOCAL_FRACTION, MAX_GROWTH_OF_NORM, StepControl, output_times, step_refusal

__all__ = ["GRID_LIMIT", "GRID_MAX", "CHUNK_FLOATS", "fits_grid", "check_forced_grid", "GridRhs", "GridMarchResult", "march_on_grid",
           "grid_region", "GridMarchFailure"]

#: Largest number of state values (grid nodes x unknowns) marched as one array; 0 sends every problem to
#: the train march. Measured (benchmarks/README.md, 'grid march'): faster than the train march on
#: coupled.yaml (8000 x 3 values: 4x) and on the rigid body with 8 nodes per IC (1.6e6 values: 2.1x, peak
#: memory ~1 GB); with 10 nodes (6e6 values) still 1.2x, but at 2.9 GB: the limit stops below that.
GRID_LIMIT = 2 ** 21


#: Most state values ``solver.march: grid`` accepts: the march holds ~20 arrays of the state (its 16
#: stages among them), ~5 GB at this size; above it the error names ``solver.march``.
GRID_MAX = 2 ** 25

#: Floats of stored values (time nodes x unknowns x grid nodes) compressed together: 256 MB. A long march
#: (thousands of time nodes) is compressed by runs and joined (:func:`pgdcli.algorithms.space_time.join_and_round`).
CHUNK_FLOATS = 2 ** 25


def fits_grid(system: NonlinearSystem) -> bool:
    """Whether the system's state (grid nodes x unknowns) has at most :data:`GRID_LIMIT` values."""
    return int(np.prod(system.shape)) * len(system.unknowns) <= GRID_LIMIT


def check_forced_grid(problem) -> None:
    """Refuse ``solver.march: grid`` on a state above :data:`GRID_MAX` values (the spec's node counts)."""
    if getattr(problem.solver, "march", "auto") != "grid":
        return
    values = len(problem.unknowns)
    for c in problem.coordinates:
        if c.name != problem.time:
            values *= c.nodes
    if values > GRID_MAX:
        raise SolverError(f"{problem.source}: solver.march: 'grid' holds ~20 arrays of the state, which has "
                          f"{values:,} values (grid nodes x unknowns; at most {GRID_MAX:,}): use 'auto' or "
                          f"'train' (a tensor train), or fewer nodes")


class GridMarchFailure(Exception):
    """The grid march stopped (blow-up, step-size underflow, max_steps); ``time``, ``values`` (m, N) and
    ``blowup_time`` say where."""

    def __init__(self, message: str, time: float, values: np.ndarray, blowup_time: float | None = None):
        super().__init__(message)
        self.time, self.values, self.blowup_time = time, values, blowup_time


class GridRhs:
    """``f_s(t, p, u)`` on arrays: ``Y`` of shape (unknowns, grid nodes) -> same shape.

    Coefficients that do not depend on time are expanded to the grid once.
    """

    def __init__(self, system: NonlinearSystem):
        self.system = system
        self.stats: dict = {}
        self.shape = system.shape
        self.fixed: dict = {}
        for s, monomials in enumerate(system.rhs):
            for m, (coef, _) in enumerate(monomials):
                timed = any(f is not None for f in coef.time_funcs) or any(
                    j.time_func is not None or j.train.timed for j in coef.joints)
                if not timed:
                    self.fixed[s, m] = coef.at(0.0).full().reshape(-1)

    def __call__(self, t: float, Y: np.ndarray) -> np.ndarray:
        out = np.zeros_like(Y)
        for s, monomials in enumerate(self.system.rhs):
            for m, (coef, factors) in enumerate(monomials):
                term = self.fixed.get((s, m))
                if term is None:
                    term = coef.at(t).full().reshape(-1)
                for i in factors:
                    term = term * Y[i]
                out[s] += term
            part = self.system.general[s] if self.system.general else None
            if part is not None:
                arrays = {name: Y[i].reshape(self.shape) for name, i in part.needed}
                values = part.grid_values(t, arrays).reshape(-1)
                if not np.all(np.isfinite(values)) and np.all(np.isfinite(Y)):  # sqrt(-1), 1/0: for the message
                    self.stats["cross_nonfinite"] = self.stats.get("cross_nonfinite", 0) + 1
                out[s] += values
        return out


@dataclass
class GridMarchResult:
    """The codebook's space-time trains and what the march did."""

    trains: list[TT]  # per unknown: the space-time train (time nodes first, then the grid's modes)
    times: np.ndarray
    steps: int
    rejected: int
    error_estimate: float  # the accepted local error estimates added up (RMS over the grid, largest unknown)
    step_sizes: list[float] = field(default_factory=list)
    breakpoints: np.ndarray | None = None
    chunks: int = 1  # runs of time nodes compressed on their own (memory) before the join


class _Store:
    """The values at the time nodes, compressed by runs of at most :data:`CHUNK_FLOATS` floats.

    A single run is compressed once with the whole budget ``delta``; with several, run ``c`` gets
    ``delta / 2 * 2^(-(c + 1) / 2)`` (the runs are orthogonal blocks of the time mode: their errors
    add in quadrature, to at most ``delta / 2``) and the rounding of their join the rest of
    ``delta`` (the two errors add).
    """

    def __init__(self, shape: tuple[int, ...], delta: float):
        self.shape, self.delta = shape, delta
        self.buffer: list[np.ndarray] = []
        self.floats = 0  # in the buffer
        self.pieces: list[list[TT]] = []
        self.spent = 0.0  # squared Frobenius budget given to the runs
        self.rng = np.random.default_rng(7)  # the sketches' seed: same spec, same codebook

    def extend(self, values: list[np.ndarray]) -> None:
        self.buffer.extend(values)
        self.floats += sum(v.size for v in values)
        if self.floats > CHUNK_FLOATS:
            self._close_run()

    def _close_run(self) -> None:
        """Compress the buffer as the next run, with its share of the budget."""
        budget = 0.5 * self.delta * np.sqrt(0.5 ** (len(self.pieces) + 1))
        self.spent += budget * budget
        self.pieces.append(self._compress(budget))

    def _compress(self, delta: float) -> list[TT]:
        stacked = np.stack(self.buffer)  # (time nodes, unknowns, grid nodes)
        self.buffer, self.floats = [], 0
        trains: list[TT] = []
        guesses = self.pieces[-1] if self.pieces else []
        for i in range(stacked.shape[1]):  # sketches sized from the ranks of the unknown (run) before
            values = np.ascontiguousarray(stacked[:, i]).reshape((stacked.shape[0],) + self.shape)
            guess = trains[-1].ranks if trains else (guesses[i].ranks if guesses else ())
            trains.append(tt_from_full_sketched(values, delta, self.rng, guess))
        return trains

    def trains(self) -> list[TT]:
        """The space-time train of every unknown, within ``delta`` of the stored values."""
        if not self.pieces:
            return self._compress(self.delta)
        if self.buffer:
            self._close_run()
        groups = [[piece[i] for piece in self.pieces] for i in range(len(self.pieces[0]))]
        return join_and_round(groups, self.delta - np.sqrt(self.spent), self.rng, batched=False, lifted=True)


def march_on_grid(system: NonlinearSystem, tolerance: float, delta: float, *, max_steps: int = 20000,
                  callback=None, slab_nodes: int | None = None) -> GridMarchResult:
    """March the whole grid array with DOP853 to the end of the time domain; compress it to trains.

    Parameters
    ----------
    system : NonlinearSystem
    tolerance : float
        Root-mean-square over the grid nodes, per unknown, of the local errors added up over the march.
    delta : float
        Frobenius bound of the compression of each unknown's space-time array.
    max_steps : int
    callback : callable, optional
        After every accepted step: ``{"time", "end", "ranks", "steps"}`` (ranks empty).
    slab_nodes : int, optional
        Automatic slabs (see :func:`pgdcli.algorithms.march.march`).

    Raises
    ------
    GridMarchFailure
    """
    nodes = system.time_basis.nodes
    t, t_final = float(nodes[0]), float(nodes[-1])
    span = t_final - t
    rhs = GridRhs(system)
    y = np.stack([u.full().reshape(-1) for u in system.initial])
    scale0 = max(1.0, float(np.max(np.abs(y))))
    control = StepControl(span, LOCAL_FRACTION * tolerance)
    stats = rhs.stats  # "cross_nonfinite": right-hand sides not finite at finite stage values (underflow_hint)
    f = rhs(t, y)
    store = _Store(system.shape, delta)
    store.extend([y])
    times, breakpoints, sizes = [t], [t], []
    h = 0.1 * span
    steps = rejected = 0
    local_sum = np.zeros(len(y))
    watch = BlowupWatch(system, y, t_final, largest=_largest)
    while t < t_final:
        h = min(h, t_final - t)
        refusal = step_refusal(steps, rejected, max_steps, h, span, lambda: underflow_hint(system.general, stats))
        if refusal:
            raise GridMarchFailure(refusal, t, y)
        y_new, K, local = _trial_step(rhs, t, y, f, h)
        error = float(np.max(local)) if local is not None else np.inf
        ratio = control.ratio(error, h)
        if ratio > 1.0:
            rejected += 1
            # None means stage-rounding noise in the train march; without roundings, halve the step
            h = control.rejected(t, h, ratio) or 0.5 * h
            continue
        if float(np.max(np.abs(y_new))) > MAX_GROWTH_OF_NORM * scale0:
            raise GridMarchFailure("the solution blows up", t, y)
        t_new = t_final if abs(t + h - t_final) <= 1e-14 * max(1.0, abs(t_final)) else t + h
        outs = output_times(t, h, t_new, nodes, times[-1], slab_nodes)
        if slab_nodes:
            breakpoints.append(t_new)
        store.extend(_dense_output(rhs, t, h, y, y_new, K, outs, t_new))
        times.extend(outs)
        t, y, f = t_new, y_new, K[DOP853.n_stages]
        steps += 1
        sizes.append(h)
        local_sum += local
        h = control.accepted(h, ratio)
        if callback is not None:
            callback({"time": t, "end": t_final, "ranks": [], "steps": steps})
        if t < t_final:
            blowup = watch(t, sizes, y)
            if blowup is not None:
                raise GridMarchFailure("the solution blows up", t, y, blowup)
    trains = store.trains()
    return GridMarchResult(trains, np.array(times), steps, rejected, float(np.max(local_sum)), sizes,
                           np.array(breakpoints) if slab_nodes else None, max(1, len(store.pieces)))


def grid_region(system: NonlinearSystem, values: np.ndarray) -> str:
    """Where the values (unknowns, grid nodes) are largest, as 'a=0, b=1' (nodes of the grid; '' for one
    trajectory)."""
    if system.params == [SINGLE_POINT] or not np.all(np.isfinite(values)):
        return ""
    idx = np.unravel_index(int(np.argmax(np.max(np.abs(values), axis=0))), system.shape)
    return ", ".join(f"{p}={system.bases[p].nodes[i]:.4g}" for p, i in zip(system.params, idx))


def _largest(y: np.ndarray) -> float:
    return float(np.max(np.abs(y)))


def _trial_step(rhs: GridRhs, t: float, y: np.ndarray, f: np.ndarray, h: float):
    """One DOP853 trial step: ``(y_new, K, local)``; K holds the 12 stages and f(t + h, y_new), local
    the elementwise error estimate (None after a non-finite value)."""
    A, B, C, E3, E5, n = DOP853.A, DOP853.B, DOP853.C, DOP853.E3, DOP853.E5, DOP853.n_stages
    K = np.empty((n + 1 + len(DOP853.C_EXTRA),) + y.shape)
    K[0] = f
    with np.errstate(all="ignore"):
        for s in range(1, n):
            K[s] = rhs(t + C[s] * h, y + h * np.tensordot(A[s, :s], K[:s], axes=1))
        y_new = y + h * np.tensordot(B, K[:n], axes=1)
        if not np.all(np.isfinite(y_new)):
            return y_new, K, None
        K[n] = rhs(t + h, y_new)
        # scipy's DOP853 estimate per unknown from the root-mean-square over the grid (the train march's norm)
        e5 = np.sqrt(np.mean(np.tensordot(E5, K[:n + 1], axes=1) ** 2, axis=1))
        e3 = np.sqrt(np.mean(np.tensordot(E3, K[:n + 1], axes=1) ** 2, axis=1))
        if not (np.all(np.isfinite(e5)) and np.all(np.isfinite(e3))):  # stages overflowed: far too long a step
            return y_new, K, None
        denom = np.sqrt(e5 * e5 + 0.01 * e3 * e3)
        local = np.where(denom > 0.0, h * e5 * e5 / np.where(denom > 0.0, denom, 1.0), 0.0)
    return y_new, K, local if np.all(np.isfinite(local)) else None


def _dense_output(rhs: GridRhs, t: float, h: float, y: np.ndarray, y_new: np.ndarray, K: np.ndarray,
                  outs: list[float], t_new: float) -> list[np.ndarray]:
    """The arrays at the times ``outs`` inside ``(t, t_new]``: scipy's order-7 dense output of DOP853
    (three extra stages when a node lies strictly inside the step)."""
    n = DOP853.n_stages + 1
    if any(tn < t_new for tn in outs):
        with np.errstate(all="ignore"):
            for s, (a, c) in enumerate(zip(DOP853.A_EXTRA, DOP853.C_EXTRA), start=n):
                K[s] = rhs(t + c * h, y + h * np.tensordot(a[:s], K[:s], axes=1))
    inside = [tn for tn in outs if tn < t_new]
    found = []
    if inside:  # all the step's nodes in one product: weights (nodes, 18) of [y, y_new, K_0 .. K_15]
        w = np.array([dense_weights((tn - t) / h, h, DOP853.D) for tn in inside])
        values = w[:, 2:] @ K.reshape(K.shape[0], -1) + np.outer(w[:, 0], y) + np.outer(w[:, 1], y_new)
        found = list(values.reshape((len(inside),) + y.shape))
    return found + [y_new] * (len(outs) - len(inside))
