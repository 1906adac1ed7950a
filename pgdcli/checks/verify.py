"""Check a codebook against an independent reference (``pgd verify``).

The problem stored in the codebook (its embedded spec) is integrated again
with scipy's ``solve_ivp`` (:mod:`pgdcli.checks.reference`, which shares no code with
the PGD solver) at sample points of the parameter box, and the codebook is
compared with it at every time node of the codebook's time grid plus random
times.

Problems with space coordinates (``der(u, x)``, boundary conditions): the
space coordinates are not sampled; the reference is the method of lines of
:func:`pgdcli.checks.reference.solve_reference_pde` (Chebyshev collocation, BDF), and
at every parameter point and time both are compared on the tensor grid of, per
space coordinate, every node of that coordinate in the codebook plus
``space_points`` random points of its domain (seeded). ``where`` then names the
space coordinates too; the settings gain ``space_points`` (points per space
coordinate), ``random_space_points`` and ``space_nodes`` (collocation nodes of
the reference per space coordinate).

Sample points: ``samples`` scrambled Sobol (or Latin hypercube) points of the
parameter box (the coordinates other than time and space), plus all ``2**m``
corners of the box (at most :data:`MAX_CORNERS`; beyond that a seeded random
subset of corners), or the points of a CSV file instead.

Figures, per unknown ``u``, over every successful sample point and time:

- ``max_abs_error = max |u_codebook - u_reference|``
- ``reference_scale = max |u_reference|``
- ``max_rel_error = max_abs_error / reference_scale`` (relative to the
  unknown's magnitude, not pointwise: a pointwise ratio explodes where the
  solution crosses zero)
- ``rms_error = sqrt(mean((u_codebook - u_reference)**2))``
- ``where``: all coordinates (time included) of the largest error.

See ``docs/verify.md`` for the JSON schema.
"""

from __future__ import annotations

import csv
import io
import math
import os
import time as _time
import warnings
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from ..errors import CodebookError, PgdError

__all__ = ["verify", "VerifyReport", "UnknownErrors", "Failure", "VerifyError", "MAX_CORNERS", "SAMPLINGS"]

#: Most corners of the parameter box that are checked (a random subset beyond).
MAX_CORNERS = 1024
#: Random (Sobol) parameter points by default, besides the corners: ODE and steady problems, and
#: time-dependent PDEs, whose method-of-lines reference costs ~2 s per point (BDF on a 40 x 40 grid;
#: 64 + 8 corners took 104 s on heat2d, 8 + 8 corners 20 s, with 2 jobs).
DEFAULT_SAMPLES = 64
DEFAULT_SAMPLES_PDE = 4
#: Largest points file (bytes) read by verify: some 1e5 points, far more than anyone can afford.
MAX_POINTS_FILE_BYTES = 8 << 20
#: Random points per space coordinate checked besides the codebook's nodes of that coordinate.
DEFAULT_RANDOM_SPACE_POINTS = 4
SAMPLINGS = ("sobol", "lhs")
# codebook evaluations per block (bounds memory of the interpolation matrices)
_EVAL_BLOCK = 100_000


class VerifyError(PgdError):
    """Invalid verification request (options, points file)."""


@dataclass
class UnknownErrors:
    """Error figures of one unknown (see the module docstring for the definitions).

    NaN when no sample point could be integrated.
    """

    max_abs_error: float
    max_rel_error: float
    rms_error: float
    reference_scale: float
    where: dict[str, float]
    codebook_value: float
    reference_value: float

    def to_dict(self) -> dict:
        return {
            "max_abs_error": _json_float(self.max_abs_error),
            "max_rel_error": _json_float(self.max_rel_error),
            "rms_error": _json_float(self.rms_error),
            "reference_scale": _json_float(self.reference_scale),
            "where": {k: _json_float(v) for k, v in self.where.items()},
            "codebook_value": _json_float(self.codebook_value),
            "reference_value": _json_float(self.reference_value),
        }


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
        The gate given to :func:`verify` (used by :meth:`to_dict`).
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

    @property
    def n_points(self) -> int:
        """Parameter points checked (including failed ones)."""
        return int(self.settings.get("parameter_points", 0))

    def violations(self, max_error: float | None = None, max_rel_error: float | None = None) -> list[str]:
        """Reasons the check fails (empty when it passes), one line each."""
        reasons = []
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
        return reasons

    def passed(self, max_error: float | None = None, max_rel_error: float | None = None) -> bool:
        """True when every reference integration succeeded and the given tolerances hold.

        Parameters
        ----------
        max_error : float, optional
            Largest allowed absolute error of every unknown.
        max_rel_error : float, optional
            Largest allowed relative error (``max_abs_error / reference_scale``).
        """
        return not self.violations(max_error, max_rel_error)

    def to_dict(self) -> dict:
        """The JSON report (``pgd verify --format json``); keys in docs/verify.md."""
        return {
            "codebook": self.codebook,
            "problem": self.problem,
            "passed": self.passed(self.max_error, self.max_rel_error),
            "gate": {"max_error": self.max_error, "max_rel_error": self.max_rel_error},
            "settings": dict(self.settings),
            "unknowns": {name: stats.to_dict() for name, stats in self.unknowns.items()},
            "failures": {"count": len(self.failures), "points": [f.to_dict() for f in self.failures]},
            "wall_time": float(self.wall_time),
        }


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------
def _json_float(value: float) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def _format_point(point: Mapping[str, float]) -> str:
    return ", ".join(f"{k}={float(v):.6g}" for k, v in point.items()) or "(no parameters)"


def _check_int(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise VerifyError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _check_tolerance(name: str, value) -> float | None:
    if value is None:
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise VerifyError(f"{name} must be a number >= 0, got {value!r}") from None
    if not (math.isfinite(number) and number >= 0):
        raise VerifyError(f"{name} must be a finite number >= 0, got {value!r}")
    return number


def _space(problem) -> tuple:
    """Space coordinates of the problem (discretized by the reference, not sampled)."""
    return tuple(c for c in problem.coordinates if getattr(c, "role", "") == "space")


def _sampled(problem) -> tuple:
    """Coordinates whose points verify samples: neither time nor space."""
    return tuple(c for c in problem.coordinates if c.name != problem.time and getattr(c, "role", "") != "space")


def _parse_problem(cb, source: str):
    from ..problem.spec import parse_spec

    if not cb.spec_text.strip():
        raise CodebookError(f"{source}: the codebook holds no problem spec; it cannot be verified")
    try:
        problem = parse_spec(cb.spec_text, source=source, allow_nonlinear=True)
    except TypeError:  # pragma: no cover - a parse_spec without allow_nonlinear
        problem = parse_spec(cb.spec_text, source=source)
    spec_coords = [(c.name, tuple(map(float, c.domain))) for c in problem.coordinates]
    cb_coords = [(c.name, tuple(map(float, c.domain))) for c in cb.coordinates]
    if spec_coords != cb_coords:
        raise CodebookError(f"{source}: the embedded spec's coordinates {spec_coords} do not match the codebook's "
                            f"{cb_coords}")
    missing = [u for u in problem.unknown_names if u not in cb.fields]
    if missing:
        raise CodebookError(f"{source}: the codebook lacks the unknown(s) {', '.join(missing)} of its spec")
    return problem


def read_points(path: str | os.PathLike, problem) -> dict[str, np.ndarray]:
    """Parameter points from a CSV file whose header names the non-time coordinates.

    Raises
    ------
    VerifyError
        Unreadable file, unknown/missing/time column, non-numbers, points
        outside the domain, no rows.
    """
    source = str(path)
    names = [c.name for c in _sampled(problem)]
    try:
        with open(path, "rb") as handle:  # at most one byte past the limit (/dev/zero is refused, not read)
            data = handle.read(MAX_POINTS_FILE_BYTES + 1)
        if len(data) > MAX_POINTS_FILE_BYTES:
            raise VerifyError(f"{source}: points file larger than {MAX_POINTS_FILE_BYTES} bytes (each point "
                              f"costs a reference solve)")
        rows = list(csv.reader(io.StringIO(data.decode("utf-8-sig"), newline="")))
    except csv.Error as exc:
        raise VerifyError(f"{source}: not a CSV points file ({' '.join(str(exc)[:200].split())})") from None
    except FileNotFoundError:
        raise VerifyError(f"{source}: no such points file") from None
    except IsADirectoryError:
        raise VerifyError(f"{source}: is a directory, expected a CSV points file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise VerifyError(f"{source}: cannot read points file ({' '.join(str(exc).split())})") from None
    if not rows:
        raise VerifyError(f"{source}: empty points file; expected a CSV header naming {', '.join(names)}")
    header = [h.strip() for h in rows[0]]
    for h in header:
        if h == problem.time:
            raise VerifyError(f"{source}: column {h!r} is the time coordinate; the points give the parameters "
                              f"({', '.join(names)}) and times are chosen by verify")
        if h in [c.name for c in _space(problem)]:
            raise VerifyError(f"{source}: column {h!r} is a space coordinate; the points give the parameters "
                              f"({', '.join(names)}) and space points are chosen by verify")
        if h not in names:
            raise VerifyError(f"{source}: unknown column {h[:40]!r}; expected the parameter coordinates "
                              f"{', '.join(names) or '(none)'}")
    if len(set(header)) != len(header):
        raise VerifyError(f"{source}: a column is repeated in the header {','.join(header)}")
    missing = [n for n in names if n not in header]
    if missing:
        raise VerifyError(f"{source}: missing column(s) {', '.join(missing)}")
    data = []
    for line, row in enumerate(rows[1:], start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise VerifyError(f"{source}: line {line}: expected {len(header)} values, got {len(row)}")
        try:
            values = [float(cell) for cell in row]
        except ValueError:
            raise VerifyError(f"{source}: line {line}: not a number in {','.join(row)[:80]!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise VerifyError(f"{source}: line {line}: values must be finite")
        data.append(values)
    if not data:
        raise VerifyError(f"{source}: no points (only a header)")
    array = np.array(data, dtype=float).reshape(-1, len(header))
    points = {h: array[:, i] for i, h in enumerate(header)}
    _check_points_domain(points, problem, source)
    return {n: points[n] for n in names}


def _check_points_domain(points: Mapping[str, np.ndarray], problem, source: str) -> None:
    for c in _sampled(problem):
        low, high = c.domain
        values = points[c.name]
        bad = ~((values >= low) & (values <= high))
        if bad.any():
            raise VerifyError(f"{source}: coordinate {c.name!r}: value {float(values[bad][0])!r} is outside the "
                              f"domain [{low:g}, {high:g}]")


def default_samples(problem) -> int:
    """Random parameter points checked by default besides the corners.

    :data:`DEFAULT_SAMPLES`, except for a time-dependent problem with space
    coordinates (a reference of ~2 s per point): :data:`DEFAULT_SAMPLES_PDE`,
    raised to the power of two at or above the element count of its finest
    linear parameter coordinate. A scrambled Sobol sample of ``2^m`` points puts
    one point in each of ``2^m`` equal intervals of every coordinate, so every
    element of a uniform linear coordinate, where a wrong nodal value stays
    local, is visited; a Chebyshev coordinate's nodal values act on its whole
    interval, and the corners and any point see them.
    """
    if problem.time is None or not _space(problem):
        return DEFAULT_SAMPLES
    elements = max((c.nodes - 1 for c in _sampled(problem) if c.discretization == "linear"), default=1)
    return min(DEFAULT_SAMPLES, max(DEFAULT_SAMPLES_PDE, 1 << (elements - 1).bit_length()))


def _sample_box(problem, n: int, sampling: str, seed: int) -> dict[str, np.ndarray]:
    from scipy.stats import qmc

    coords = _sampled(problem)
    m = len(coords)
    if sampling == "sobol":
        engine = qmc.Sobol(d=m, scramble=True, seed=seed)
    else:
        engine = qmc.LatinHypercube(d=m, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Sobol: "balance properties" when n is not a power of 2
        unit = engine.random(n)
    low = np.array([c.domain[0] for c in coords])
    high = np.array([c.domain[1] for c in coords])
    box = low + unit * (high - low)
    box = np.minimum(np.maximum(box, low), high)
    return {c.name: box[:, j] for j, c in enumerate(coords)}


def _corners(problem, seed: int, max_corners: int) -> tuple[dict[str, np.ndarray], int]:
    """Corners of the parameter box (a seeded random subset beyond max_corners) and their total number."""
    coords = _sampled(problem)
    m = len(coords)
    total = 2**m
    if total <= max_corners:
        bits = (np.arange(total)[:, None] >> np.arange(m)[::-1][None, :]) & 1
    else:
        rng = np.random.default_rng([seed, 2])
        chosen = np.zeros((0, m), dtype=int)
        while chosen.shape[0] < max_corners:
            more = rng.integers(0, 2, size=(max_corners, m))
            chosen = np.unique(np.vstack([chosen, more]), axis=0)
        bits = chosen[rng.permutation(chosen.shape[0])[:max_corners]]
    points = {c.name: np.where(bits[:, j] == 1, c.domain[1], c.domain[0]).astype(float) for j, c in enumerate(coords)}
    return points, total


def _evaluate_codebook(cb, samples: Mapping[str, np.ndarray], time: str, times: np.ndarray, unknowns) -> dict:
    S = len(next(iter(samples.values()))) if samples else 1
    T = times.size
    out = {u: np.empty((S, T)) for u in unknowns}
    block = max(1, _EVAL_BLOCK // max(T, 1))
    for start in range(0, S, block):
        rows = slice(start, min(S, start + block))
        coords = {}
        for c in cb.coordinates:
            coords[c.name] = times[None, :] if c.name == time else samples[c.name][rows, None]
        values = cb.evaluate(coords, fields=list(unknowns))
        for u in unknowns:
            out[u][rows] = np.broadcast_to(values[u], (rows.stop - rows.start, T))
    return out


def _statistics(coordinates, time, samples, times, ok, reference, approx, space_points=None) -> UnknownErrors:
    """Figures over the successful samples; values (S, T) or, with space coordinates, (S, T, X_1, ..., X_d)
    with the space axes in the order of ``space_points``."""
    if not ok.any():
        nan = float("nan")
        return UnknownErrors(nan, nan, nan, nan, {c: nan for c in coordinates}, nan, nan)
    space_points = space_points or {}
    ref = reference[ok]
    cbv = approx[ok]
    err = np.abs(cbv - ref)
    index = np.unravel_index(int(np.argmax(err)), err.shape)
    i, j = index[0], index[1]
    at_space = {c: float(points[k]) for (c, points), k in zip(space_points.items(), index[2:])}
    max_abs = float(err[index])
    scale = float(np.max(np.abs(ref)))
    if scale > 0:
        rel = max_abs / scale
    else:
        rel = 0.0 if max_abs == 0 else float("inf")
    rows = np.flatnonzero(ok)
    where = {c: float(times[j]) if c == time else at_space[c] if c in at_space else float(samples[c][rows[i]])
             for c in coordinates}
    return UnknownErrors(
        max_abs_error=max_abs,
        max_rel_error=float(rel),
        rms_error=float(np.sqrt(np.mean(err**2))),
        reference_scale=scale,
        where=where,
        codebook_value=float(cbv[index]),
        reference_value=float(ref[index]),
    )


def codebook_on_space_grid(cb, samples: Mapping[str, np.ndarray], S: int, time: str, times: np.ndarray,
                             space_points: Mapping[str, np.ndarray], unknowns) -> dict:
    """Codebook values (S, T, X_1, ..., X_d) on the tensor grid of the space points (a steady problem:
    ``time`` None and one placeholder time), in blocks of samples that bound the memory."""
    space = list(space_points)
    d = len(space)
    shape = tuple(space_points[c].size for c in space)
    per_sample = times.size * int(np.prod(shape))
    out = {u: np.empty((S, times.size) + shape) for u in unknowns}
    block = max(1, _EVAL_BLOCK // max(per_sample, 1))
    for start in range(0, S, block):
        rows = slice(start, min(S, start + block))
        n = rows.stop - rows.start
        coords = {}
        for c in cb.coordinates:
            if c.name == time:
                coords[c.name] = times.reshape((1, -1) + (1,) * d)
            elif c.name in space_points:
                k = space.index(c.name)
                coords[c.name] = space_points[c.name].reshape((1, 1) + tuple(-1 if m == k else 1 for m in range(d)))
            else:
                coords[c.name] = samples[c.name][rows].reshape((-1, 1) + (1,) * d)
        values = cb.evaluate(coords, fields=list(unknowns))
        for u in unknowns:
            out[u][rows] = np.broadcast_to(values[u], (n, times.size) + shape)
    return out


# ----------------------------------------------------------------------------------------------
# public API
# ----------------------------------------------------------------------------------------------
def verify(
    codebook,
    *,
    samples: int | None = None,
    sampling: str = "sobol",
    seed: int = 0,
    points: str | os.PathLike | Mapping[str, object] | None = None,
    times: int = 16,
    method: str | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    jobs: int | None = None,
    max_error: float | None = None,
    max_rel_error: float | None = None,
    max_corners: int = MAX_CORNERS,
    progress: Callable[[int, int], None] | None = None,
    space_points: int = DEFAULT_RANDOM_SPACE_POINTS,
    space_nodes: int | Mapping[str, int] | None = None,
) -> VerifyReport:
    """Compare a codebook with an independent ``solve_ivp`` reference of its own problem.

    Parameters
    ----------
    codebook : Codebook or path
    samples : int, optional
        Random points of the parameter box (>= 1), in addition to its corners
        [default: :data:`DEFAULT_SAMPLES`; :data:`DEFAULT_SAMPLES_PDE` for a
        time-dependent problem with space coordinates].
    sampling : {'sobol', 'lhs'}
        Scrambled Sobol or Latin hypercube (``scipy.stats.qmc``).
    seed : int
        Seed of the sampling and of the random times.
    points : path or mapping, optional
        Check these parameter points instead (no random samples, no
        corners): a CSV file whose header names the non-time coordinates, or
        a mapping coordinate -> 1-D array.
    times : int
        Random times (>= 0) in addition to every node of the time coordinate.
    method : str, optional
        ``solve_ivp`` method: DOP853 (default), RK45, Radau, BDF or LSODA. With
        space coordinates the method-of-lines system is stiff: BDF (default)
        or Radau; any other method given is replaced by BDF (the settings
        record the method used).
    rtol, atol : float, optional
        ``solve_ivp`` tolerances (default 1e-12 and 1e-12; with space
        coordinates 1e-10 and 1e-12).
    jobs : int, optional
        Worker processes (default: ``os.cpu_count()``; 1: no pool).
    max_error, max_rel_error : float, optional
        The gate recorded in the report (see :meth:`VerifyReport.passed`).
    max_corners : int
        Most corners checked; beyond, a seeded random subset.
    progress : callable, optional
        ``progress(done, total)`` in parameter points, after each chunk.
    space_points : int
        With space coordinates: random points (>= 0) per space coordinate, in
        addition to every node of that coordinate in the codebook; the
        codebook and the reference are compared on the tensor grid of these
        points, at every parameter point and time.
    space_nodes : int or dict of str to int, optional
        With space coordinates: collocation nodes per space coordinate of the
        method-of-lines reference (default
        :data:`pgdcli.checks.reference.DEFAULT_SPACE_NODES`).

    Returns
    -------
    VerifyReport

    Raises
    ------
    PgdError
        Unreadable codebook, a codebook without spec, invalid options or
        points (:class:`VerifyError`).
    """
    from ..codebook.codebook import Codebook
    from .reference import DEFAULT_SPACE_NODES, METHODS, PDE_METHODS, solve_reference, solve_reference_pde

    started = _time.perf_counter()
    if samples is not None:
        samples = _check_int("samples", samples, 1)
    times_count = _check_int("times", times, 0)
    seed = _check_int("seed", seed, 0)
    max_corners = _check_int("max_corners", max_corners, 0)
    jobs = (os.cpu_count() or 1) if jobs is None else _check_int("jobs", jobs, 1)
    if sampling not in SAMPLINGS:
        raise VerifyError(f"sampling must be one of {', '.join(SAMPLINGS)}, got {sampling!r}")
    if method is not None and method not in METHODS:
        raise VerifyError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    random_space = _check_int("space_points", space_points, 0)
    for label, value in (("rtol", rtol), ("atol", atol)):
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) \
                or not (math.isfinite(value) and 0 < value < 1):
            raise VerifyError(f"{label} must be a number in (0, 1), got {value!r}")
    max_error = _check_tolerance("max_error", max_error)
    max_rel_error = _check_tolerance("max_rel_error", max_rel_error)

    if isinstance(codebook, Codebook):
        cb, path = codebook, None
        source = f"<codebook {cb.name}>"
    else:
        path = str(codebook)
        cb = Codebook.load(codebook)
        source = path
    problem = _parse_problem(cb, source)
    time = problem.time
    params = _sampled(problem)
    names = [c.name for c in params]
    space = [c.name for c in _space(problem)]
    if samples is None:
        samples = default_samples(problem)
    if space:
        method = method if method in PDE_METHODS else "BDF"
        rtol = 1e-10 if rtol is None else rtol
    else:
        method = "DOP853" if method is None else method
        rtol = 1e-12 if rtol is None else rtol
    atol = 1e-12 if atol is None else atol

    settings: dict = {"sampling": sampling, "samples": samples, "seed": seed, "corners": 0, "corners_total": 2 ** len(names),
                      "points_file": None}
    if points is not None:
        if isinstance(points, Mapping):
            extra = [k for k in points if k not in names]
            if extra:
                raise VerifyError(f"points: unknown coordinate {extra[0]!r}; expected {', '.join(names) or '(none)'}")
            missing = [n for n in names if n not in points]
            if missing:
                raise VerifyError(f"points: missing coordinate(s) {', '.join(missing)}")
            sample_points = {n: np.atleast_1d(np.asarray(points[n], dtype=float)) for n in names}
            if len({a.shape for a in sample_points.values()}) > 1 or any(a.ndim != 1 for a in sample_points.values()):
                raise VerifyError("points: expected 1-D arrays of one length")
            if any(not np.isfinite(a).all() for a in sample_points.values()):
                raise VerifyError("points: values must be finite")
            _check_points_domain(sample_points, problem, "points")
        else:
            sample_points = read_points(points, problem)
            settings["points_file"] = str(points)
        S = len(next(iter(sample_points.values()))) if names else 1
        settings.update(sampling="points", samples=S, corners_total=0)
    elif names:
        random_points = _sample_box(problem, samples, sampling, seed)
        corner_points, total = _corners(problem, seed, max_corners)
        sample_points = {n: np.concatenate([random_points[n], corner_points[n]]) for n in names}
        S = samples + len(next(iter(corner_points.values())))
        settings.update(corners=S - samples, corners_total=total)
    else:
        sample_points, S = {}, 1  # no parameters: one trajectory
        settings.update(samples=1, corners_total=0)

    if time is None:
        all_times = np.zeros(1)  # steady: one placeholder time axis, dropped from the report
        time_counts = dict(random_times=0, time_nodes=0, times=0)
    else:
        time_coordinate = cb.coordinate(time)
        nodes = np.asarray(time_coordinate.basis().nodes, dtype=float)
        t_low, t_high = time_coordinate.domain
        rng = np.random.default_rng([seed, 1])
        random_times = rng.uniform(t_low, t_high, times_count)
        all_times = np.unique(np.clip(np.concatenate([nodes, random_times]), t_low, t_high))
        time_counts = dict(random_times=times_count, time_nodes=int(nodes.size), times=int(all_times.size))
    settings.update(
        parameter_points=int(S),
        **time_counts,
        method="direct" if time is None else method,  # steady: one sparse LU solve per point
        rtol=float(rtol),
        atol=float(atol),
        jobs=int(jobs),
    )

    def report_progress(done: int) -> None:
        if progress is not None:
            progress(done, S)

    report_progress(0)
    unknowns = list(problem.unknown_names)
    coordinates = cb.coordinate_names
    if space:
        # every node of each space coordinate in the codebook, plus random points
        space_grid = {}
        for k, name in enumerate(space):
            c = cb.coordinate(name)
            low, high = map(float, c.domain)
            extra = np.random.default_rng([seed, 3, k]).uniform(low, high, random_space)
            space_grid[name] = np.unique(np.clip(np.concatenate([np.asarray(c.basis().nodes, dtype=float), extra]),
                                                 low, high))
        nodes = DEFAULT_SPACE_NODES if space_nodes is None else space_nodes
        result = solve_reference_pde(problem, sample_points, space_grid, None if time is None else all_times,
                                     grid=True, method=method, rtol=rtol, atol=atol, jobs=jobs,
                                     progress=report_progress, space_nodes=nodes)
        if time is None:  # the placeholder time axis, as the codebook values have it
            result.values = {u: v[:, None] for u, v in result.values.items()}
        approx = codebook_on_space_grid(cb, sample_points, S, time, all_times, space_grid, unknowns)
        settings.update(
            space_points={n: int(space_grid[n].size) for n in space},
            random_space_points=random_space,
            space_nodes=dict(result.nodes),
        )
    else:
        space_grid = {}
        result = solve_reference(problem, sample_points, all_times, method=method, rtol=rtol, atol=atol, jobs=jobs,
                                 progress=report_progress)
        approx = _evaluate_codebook(cb, sample_points, time, all_times, unknowns)
    stats = {u: _statistics(coordinates, time, sample_points, all_times, result.success, result.values[u], approx[u],
                            space_grid)
             for u in unknowns}
    failures = [
        Failure({n: float(sample_points[n][i]) for n in names}, result.messages[i] or "integration failed")
        for i in np.flatnonzero(~result.success)
    ]
    reference = result.values
    if time is None:
        all_times = np.zeros(0)
        reference = {u: v[:, 0] for u, v in reference.items()}
        approx = {u: v[:, 0] for u, v in approx.items()}
    return VerifyReport(
        codebook=path,
        problem=problem.name,
        time=time,
        coordinates=list(coordinates),
        unknowns=stats,
        failures=failures,
        settings=settings,
        max_error=max_error,
        max_rel_error=max_rel_error,
        samples=sample_points,
        times=all_times,
        reference=reference,
        codebook_values=approx,
        wall_time=_time.perf_counter() - started,
        space_points=space_grid,
    )
