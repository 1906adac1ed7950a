"""Where a codebook is checked: parameter points (random, corners, given), times and space points.

``pgd verify`` samples the parameter box (Sobol or Latin hypercube, plus its corners); the solve-time
check samples the codebook's own grid (:func:`check_sample`: corners, face nodes, uniform points;
:func:`line_sample`: points off the nodes in one coordinate at a time).

Shared by ``pgd verify`` (:mod:`pgdcli.checks.verify`) and the solve-time check (:mod:`pgdcli.checks.check`).
"""

from __future__ import annotations

import csv
import io
import math
import os
import warnings
from typing import Mapping

import numpy as np

from ..errors import VerifyError
from .reference_base import sampled_coordinates, space_coordinates  # one definition for references and samples

__all__ = ["MAX_CORNERS", "SAMPLINGS", "space_coordinates", "sampled_coordinates", "read_points", "check_points_domain",
           "default_samples", "sample_box", "box_corners", "parameter_points", "check_times", "space_points_grid",
           "check_sample", "line_sample", "nodes_and_midpoints", "checked_time_nodes", "CHECK_TIME_NODES", "CORNERS",
           "FACE_NODES", "BETWEEN", "LINE", "CORNER_LINES"]


#: Most corners of the parameter box that are checked (a random subset beyond).
MAX_CORNERS = 1024
#: Random (Sobol) parameter points by default, besides the corners: ODE and steady problems, and
#: time-dependent PDEs, whose method-of-lines reference (BDF on a 40 x 40 grid) costs seconds per
#: point: the default sample keeps ``pgd verify`` of the 2-D heat problem under half a minute.
DEFAULT_SAMPLES = 64
DEFAULT_SAMPLES_PDE = 4
#: Largest points file (bytes) read by verify: some 1e5 points, far more than anyone can afford.
MAX_POINTS_FILE_BYTES = 8 << 20
#: Random points per space coordinate checked besides the codebook's nodes of that coordinate.
DEFAULT_RANDOM_SPACE_POINTS = 4
#: Time nodes the checks compare at, at most. A march's codebook has a slab per step (a stiff
#: problem: ~1e5 nodes), and its reference costs a solve_ivp segment per output time; beyond this,
#: every k-th node (the last always): spread over the whole time domain.
CHECK_TIME_NODES = 1024
SAMPLINGS = ("sobol", "lhs")

def read_points(path: str | os.PathLike, problem) -> dict[str, np.ndarray]:
    """Parameter points from a CSV file whose header names the non-time coordinates.

    Raises
    ------
    VerifyError
        Unreadable file, unknown/missing/time column, non-numbers, points
        outside the domain, no rows.
    """
    source = str(path)
    names = [c.name for c in sampled_coordinates(problem)]
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
        if h in [c.name for c in space_coordinates(problem)]:
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
    check_points_domain(points, problem, source)
    return {n: points[n] for n in names}


def check_points_domain(points: Mapping[str, np.ndarray], problem, source: str) -> None:
    for c in sampled_coordinates(problem):
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
    if problem.time is None or not space_coordinates(problem):
        return DEFAULT_SAMPLES
    elements = max((c.nodes - 1 for c in sampled_coordinates(problem) if c.discretization == "linear"), default=1)
    return min(DEFAULT_SAMPLES, max(DEFAULT_SAMPLES_PDE, 1 << (elements - 1).bit_length()))


def sample_box(problem, n: int, sampling: str, seed: int) -> dict[str, np.ndarray]:
    from scipy.stats import qmc

    coords = sampled_coordinates(problem)
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


def box_corners(problem, seed: int, max_corners: int) -> tuple[dict[str, np.ndarray], int]:
    """Corners of the parameter box (a seeded random subset beyond max_corners) and their total number."""
    coords = sampled_coordinates(problem)
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


def parameter_points(problem, points, samples: int, sampling: str, seed: int,
                     max_corners: int) -> tuple[dict[str, np.ndarray], int, dict]:
    """The parameter points checked: given ``points`` (a CSV path or a mapping), else ``samples``
    random points of the box plus its corners.

    Returns
    -------
    points : dict of str to ndarray, shape (S,)
    S : int
        Number of points (1 without parameters: one trajectory).
    settings : dict
        The sampling part of the report's settings.
    """
    names = [c.name for c in sampled_coordinates(problem)]
    settings: dict = {"sampling": sampling, "samples": samples, "seed": seed, "corners": 0,
                      "corners_total": 2 ** len(names), "points_file": None}
    if points is not None:
        if isinstance(points, Mapping):
            sample_points = _given_points(points, problem, names)
        else:
            sample_points = read_points(points, problem)
            settings["points_file"] = str(points)
        S = len(next(iter(sample_points.values()))) if names else 1
        settings.update(sampling="points", samples=S, corners_total=0)
    elif names:
        random_points = sample_box(problem, samples, sampling, seed)
        corner_points, total = box_corners(problem, seed, max_corners)
        sample_points = {n: np.concatenate([random_points[n], corner_points[n]]) for n in names}
        S = samples + len(next(iter(corner_points.values())))
        settings.update(corners=S - samples, corners_total=total)
    else:
        sample_points, S = {}, 1  # no parameters: one trajectory
        settings.update(samples=1, corners_total=0)
    return sample_points, S, settings


def _given_points(points: Mapping, problem, names: list[str]) -> dict[str, np.ndarray]:
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
    check_points_domain(sample_points, problem, "points")
    return sample_points


def check_times(cb, time: str | None, seed: int, count: int) -> tuple[np.ndarray, dict]:
    """Every node of the time coordinate plus ``count`` seeded random times, sorted and unique, and
    their counts for the report (steady: one placeholder time)."""
    if time is None:
        return np.zeros(1), dict(random_times=0, time_nodes=0, times=0)
    time_coordinate = cb.coordinate(time)
    nodes = np.asarray(time_coordinate.basis().nodes, dtype=float)
    picked, stride = checked_time_nodes(nodes)
    t_low, t_high = time_coordinate.domain
    rng = np.random.default_rng([seed, 1])
    random_times = rng.uniform(t_low, t_high, count)
    all_times = np.unique(np.clip(np.concatenate([nodes[picked], random_times]), t_low, t_high))
    counts = dict(random_times=count, time_nodes=int(picked.size), times=int(all_times.size))
    if stride > 1:
        counts |= dict(time_nodes_total=int(nodes.size), time_node_stride=stride)
    return all_times, counts


def space_points_grid(cb, space: list[str], seed: int, count: int) -> dict[str, np.ndarray]:
    """Per space coordinate: every node of it in the codebook plus ``count`` seeded random points."""
    grid = {}
    for k, name in enumerate(space):
        c = cb.coordinate(name)
        low, high = map(float, c.domain)
        extra = np.random.default_rng([seed, 3, k]).uniform(low, high, count)
        grid[name] = np.unique(np.clip(np.concatenate([np.asarray(c.basis().nodes, dtype=float), extra]), low, high))
    return grid


# ----------------------------------------------------------------------------------------------
# the solve-time check's sample (pgdcli.checks.check)
# ----------------------------------------------------------------------------------------------
# All corners up to pgd verify's limit: the extreme dynamics sit there, and a seeded subset can miss
# the one corner where the error peaks (the 10-D rigid body: one of its 512 was just over 1e-5).
CORNERS = MAX_CORNERS
FACE_NODES = 96
BETWEEN = 96
LINE = 16
#: Per parameter coordinate, points off its nodes with every other coordinate at an end of its domain:
#: one from each corner of the others' box, up to this many (a seeded subset beyond). An error can
#: peak along one coordinate with every other one at an end of its domain, where random lines do not
#: look (the SEIRS model of tests/user_problems/seirs_wide.yaml, along E0).
CORNER_LINES = 64


def _parameter_nodes(problem, codebook) -> tuple[list[str], list[np.ndarray]]:
    names = [c.name for c in problem.parameter_coordinates]
    return names, [codebook.coordinate(n).basis().nodes for n in names]


def check_sample(problem, codebook, seed: int = 0) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Corners, face nodes and uniform points of the parameter box, and which of them are grid nodes.

    Returns
    -------
    points : dict of str to ndarray, shape (S,)
        A value per point for every parameter coordinate (``{}`` when there are none: one point).
    at_nodes : ndarray of bool, shape (S,)
    """
    names, nodes = _parameter_nodes(problem, codebook)
    if not names:
        return {}, np.ones(1, dtype=bool)
    rng = np.random.default_rng([seed, 11])
    m = len(names)
    last = [len(x) - 1 for x in nodes]
    ends = _corners(m, rng, CORNERS)
    corner_index = np.where(ends == 1, last, 0)
    face_index = np.column_stack([rng.integers(0, len(x), FACE_NODES) for x in nodes])
    on_end = rng.random((FACE_NODES, m)) < 0.5
    face_index = np.where(on_end, np.where(rng.random((FACE_NODES, m)) < 0.5, 0, last), face_index)
    index = np.unique(np.vstack([corner_index, face_index]), axis=0)
    at_grid = {n: x[index[:, j]] for j, (n, x) in enumerate(zip(names, nodes))}
    between = {n: rng.uniform(*problem.coordinate(n).domain, size=BETWEEN) for n in names}
    points = {n: np.concatenate([at_grid[n], between[n]]) for n in names}
    at_nodes = np.concatenate([np.ones(index.shape[0], dtype=bool), np.zeros(BETWEEN, dtype=bool)])
    return points, at_nodes


def line_sample(problem, codebook, seed: int = 0) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Points off the nodes in one parameter coordinate only: :data:`LINE` per coordinate with the
    others at random nodes, and one from each corner of the others' box (:data:`CORNER_LINES` at most).

    The off-node value is the midpoint of a random node interval moved by up to a
    quarter of it (the interpolation error of a polynomial peaks between nodes);
    for the first points the other coordinates sit at random nodes, half of them at an end;
    then at the ends of their domains, where the dynamics are most extreme.

    Returns
    -------
    points : dict of str to ndarray, shape (L,)
    line : ndarray of int, shape (L,)
        Index (into ``problem.parameter_coordinates``) of the coordinate off its nodes.
    """
    names, nodes = _parameter_nodes(problem, codebook)
    if not names:
        return {}, np.zeros(0, dtype=int)
    rng = np.random.default_rng([seed, 13])
    corner_rng = np.random.default_rng([seed, 17])  # its own stream: the random lines stay as they were
    cols = {n: [] for n in names}
    counts = []
    for j, (n, x) in enumerate(zip(names, nodes)):
        k = _line_intervals(codebook.coordinate(n), x, rng)
        size = k.size
        cols[n].append(x[k] + (x[k + 1] - x[k]) * (0.5 + rng.uniform(-0.25, 0.25, size)))
        for n2, x2 in zip(names, nodes):
            if n2 != n:
                idx = rng.integers(0, len(x2), size)
                ends = rng.random(size) < 0.5
                cols[n2].append(np.where(ends, x2[np.where(rng.random(size) < 0.5, 0, len(x2) - 1)], x2[idx]))
        others = [(n2, x2) for n2, x2 in zip(names, nodes) if n2 != n]
        ends = _corners(len(others), corner_rng, CORNER_LINES)
        k = corner_rng.integers(0, len(x) - 1, ends.shape[0])
        cols[n].append(x[k] + (x[k + 1] - x[k]) * (0.5 + corner_rng.uniform(-0.25, 0.25, k.size)))
        for i, (n2, x2) in enumerate(others):
            cols[n2].append(np.where(ends[:, i] == 1, x2[-1], x2[0]))
        counts.append(size + k.size)
    points = {n: np.concatenate(c) for n, c in cols.items()}
    return points, np.repeat(np.arange(len(names)), counts)


def _corners(m: int, rng, limit: int) -> np.ndarray:
    """Corners of an m-D box as 0/1 rows: all of them, or ``limit`` distinct ones drawn from ``rng`` (none
    for m = 0)."""
    if m == 0:
        return np.zeros((0, 0), dtype=int)
    if 2**m <= limit:
        return (np.arange(2**m)[:, None] >> np.arange(m)[None, :]) & 1
    ends = np.unique(rng.integers(0, 2, size=(4 * limit, m)), axis=0)
    return ends[rng.permutation(ends.shape[0])[:limit]]


def _line_intervals(info, x: np.ndarray, rng) -> np.ndarray:
    """Node intervals to sample off the nodes: :data:`LINE` random ones, and 2 in every element.

    Elements are refined where their own points show the error (:mod:`pgdcli.adapt`), so
    each needs points of its own however small it is.
    """
    k = rng.integers(0, len(x) - 1, LINE)
    bp = getattr(info, "breakpoints", ())
    if len(bp) <= 2:
        return k
    per = (len(x) - 1) // (len(bp) - 1)  # node intervals per element
    first = np.arange(len(bp) - 1) * per
    extra = first[:, None] + rng.integers(0, per, (first.size, 2))
    return np.concatenate([k, extra.ravel()])


def checked_time_nodes(nodes: np.ndarray) -> tuple[np.ndarray, int]:
    """The indices of the time nodes a check compares at, and their stride: all of them, or every
    ``stride``-th (the last always) when there are more than :data:`CHECK_TIME_NODES`."""
    stride = max(1, -(-(nodes.size - 1) // (CHECK_TIME_NODES - 1)))
    picked = np.arange(0, nodes.size, stride)
    if picked[-1] != nodes.size - 1:
        picked = np.append(picked, nodes.size - 1)
    return picked, stride


def nodes_and_midpoints(codebook, time: str) -> tuple[np.ndarray, np.ndarray]:
    """The time nodes and the midpoints between them, sorted, and which are nodes.

    Beyond :data:`CHECK_TIME_NODES` nodes, the nodes of :func:`checked_time_nodes` and the
    midpoint of the node interval after each (not of the gaps between the chosen nodes).
    """
    all_nodes = np.asarray(codebook.coordinate(time).basis().nodes, dtype=float)
    picked, _ = checked_time_nodes(all_nodes)
    nodes = all_nodes[picked]
    after = picked[picked < all_nodes.size - 1]
    mids = 0.5 * (all_nodes[after + 1] + all_nodes[after])
    times = np.concatenate([nodes, mids])
    order = np.argsort(times, kind="stable")
    is_node = np.concatenate([np.ones(nodes.size, bool), np.zeros(mids.size, bool)])
    return times[order], is_node[order]
