"""Every evaluation path of a codebook against the reference contraction of its tensor type.

The reference is :meth:`pgdcli.tensors.tt.TT.evaluate` / :meth:`pgdcli.tensors.cp.CPTensor.evaluate`
(one einsum per core, or the product of the interpolated modes) with the dense rows of
``basis.interpolation_matrix`` (values) or :func:`pgdcli.codebook.gradient.derivative_matrix`
(a derivative, in one coordinate's place). The fast paths compute the same sums in other
orders: one point (``TTStack``, the CP rows), batches (``TTBatch``, the CP chunks), series, grids,
gradients at points and on grids, and the fit's ``TrajectoryModel``. Each must agree with the
reference within a rounding-error bound: ``(sum of the contracted lengths) * eps`` times the
contraction of the absolute values (the classic bound of a recursive sum, ``gamma_n``), with
a factor 4 for the rows, which the paths compute in their own ways.

Codebooks: random trains and CP sums on every kind of coordinate (one Chebyshev interval,
Chebyshev slabs on the time and on a parameter, linear elements, two nodes), in several core
orders side by side (the one-point stack and the trains outside it), with ranks wider and
narrower than the slabs (merged first and last pairs of cores), coordinates that share one
Chebyshev node count (their weights computed together) and later coordinates of many windows
(the batch groups points by them); and the codebooks of the shipped problems that solve in
seconds (the others take minutes; their trains have the same structure as these).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import nodal_points

from pgdcli.codebook import batch_eval
from pgdcli.codebook.codebook import Codebook, CoordinateInfo
from pgdcli.codebook.gradient import TrajectoryModel, derivative_matrix
from pgdcli.tensors.cp import CPTensor
from pgdcli.tensors.tt import TT

EPS = np.finfo(float).eps

#: Shipped problems that solve in seconds: CP (parametric, spring, relaxation, forced, heat1d) and
#: tensor trains from the march (logistic, coupled, drag, pendulum, rigid_body).
CHEAP_SHIPPED = ("parametric", "spring", "relaxation", "forced", "heat1d", "logistic", "coupled", "drag",
                 "pendulum", "rigid_body")


# ----------------------------------------------------------------------------------------------
# the reference and its rounding bound
# ----------------------------------------------------------------------------------------------
def _absolute(field):
    if isinstance(field, TT):
        return TT([np.abs(c) for c in field.cores], field.mode_order)
    return CPTensor(np.abs(field.weights), [np.abs(f) for f in field.factors])


def _length(field) -> int:
    """The summed lengths of the contraction's inner sums (nodes and ranks): the ``n`` of ``gamma_n``."""
    if isinstance(field, TT):
        return sum(c.shape[0] * c.shape[1] for c in field.cores) + 1
    return sum(f.shape[0] for f in field.factors) + field.rank


def reference(field, rows: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Values of the reference contraction at the points behind ``rows`` and their rounding bound."""
    bound = 4 * _length(field) * EPS * _absolute(field).evaluate([np.abs(r) for r in rows])
    return field.evaluate(rows), bound + 1e-300


def assert_agrees(got: np.ndarray, field, rows: list[np.ndarray], what: str) -> None:
    ref, bound = reference(field, rows)
    got = np.asarray(got, dtype=float).reshape(-1)
    excess = np.abs(got - ref) / bound
    assert np.all(excess <= 1.0), f"{what}: worst |fast - reference| / bound = {excess.max():.3g}"


def value_rows(cb: Codebook, points: dict) -> list[np.ndarray]:
    return [b.interpolation_matrix(np.clip(np.asarray(points[c.name], dtype=float).reshape(-1), *c.domain))
            for c, b in zip(cb.coordinates, cb._bases)]


def derivative_rows(cb: Codebook, points: dict, j: int) -> list[np.ndarray]:
    rows = value_rows(cb, points)
    c = cb.coordinates[j]
    rows[j] = derivative_matrix(cb._bases[j], np.clip(np.asarray(points[c.name], dtype=float).reshape(-1), *c.domain))
    return rows


# ----------------------------------------------------------------------------------------------
# codebooks
# ----------------------------------------------------------------------------------------------
def _slabs(name: str, slabs: int, per_slab: int, domain, role: str) -> CoordinateInfo:
    breaks = tuple(domain[0] + (domain[1] - domain[0]) * np.linspace(0.0, 1.0, slabs + 1) ** 1.3)  # uneven
    return CoordinateInfo(name, tuple(domain), slabs * (per_slab - 1) + 1, "chebyshev", role, breaks)


def _train(rng, coords, ranks, order) -> TT:
    full = [1] + list(ranks) + [1]
    return TT([rng.standard_normal((full[k], coords[j].nodes, full[k + 1])) / np.sqrt(full[k])
               for k, j in enumerate(order)], order)


def _cp(rng, coords, rank) -> CPTensor:
    return CPTensor(rng.standard_normal(rank), [rng.standard_normal((c.nodes, rank)) for c in coords])


def random_codebooks() -> dict[str, Codebook]:
    rng = np.random.default_rng(20)
    t = _slabs("t", 6, 7, (0.0, 3.0), "time")
    a = CoordinateInfo("a", (-1.0, 2.0), 9)
    b = CoordinateInfo("b", (0.0, 1.0), 40, "linear")  # many windows: points grouped by them
    c = CoordinateInfo("c", (0.5, 1.5), 9)  # shares a's node count: weights computed together
    p = _slabs("p", 3, 8, (1.0, 4.0), "parameter")
    two = CoordinateInfo("e", (0.0, 1.0), 2, "linear")
    coords = [t, a, b, c, p, two]
    books = {
        "every kind, time first": {"u": _train(rng, coords, [10, 12, 9, 6, 2], [0, 1, 2, 3, 4, 5]),
                                   "v": _train(rng, coords, [12, 8, 5, 4, 2], [0, 1, 2, 3, 4, 5])},
        "narrow bonds, no merged pair": {"u": _train(rng, coords, [3, 4, 5, 3, 2], [0, 1, 2, 3, 4, 5])},
        "linear elements first": {"u": _train(rng, coords, [2, 9, 7, 5, 2], [2, 0, 1, 3, 4, 5])},
        "three orders side by side": {"u": _train(rng, coords, [8, 11, 6, 4, 2], [0, 1, 2, 3, 4, 5]),
                                      "w": _train(rng, coords, [6, 6, 6, 4, 2], [4, 3, 2, 1, 0, 5]),
                                      "x": _train(rng, coords, [2, 5, 9, 7, 3], [5, 2, 4, 0, 3, 1])},
        "trains beside CP sums": {"m": _cp(rng, coords, 5), "u": _train(rng, coords, [9, 10, 6, 3, 2],
                                                                       [0, 1, 2, 3, 4, 5]),
                                  "n": _cp(rng, coords, 2)},
        "CP only": {"m": _cp(rng, coords, 7), "n": _cp(rng, coords, 1)},
    }
    out = {name: Codebook(coords, fields, name=name) for name, fields in books.items()}
    out["one coordinate"] = Codebook([t], {"u": TT([rng.standard_normal((1, t.nodes, 1))], (0,)),
                                           "m": _cp(rng, [t], 3)})
    out["two coordinates"] = Codebook([a, b], {"u": _train(rng, [a, b], [6], [1, 0]), "m": _cp(rng, [a, b], 4)})
    return out


RANDOM = random_codebooks()


@pytest.fixture(scope="module", params=sorted(RANDOM) + [f"shipped {name}" for name in CHEAP_SHIPPED])
def book(request, solved) -> Codebook:
    if request.param.startswith("shipped "):
        return solved(request.param.split(" ", 1)[1]).codebook
    return RANDOM[request.param]


# ----------------------------------------------------------------------------------------------
# the reference itself: the full tensor at the nodes, a loop over the points
# ----------------------------------------------------------------------------------------------
def test_reference_is_the_full_tensor_at_the_nodes():
    """Unit rows select nodes: the reference gives the full tensor's entries (in coordinate order)."""
    cb = RANDOM["three orders side by side"]
    small = [CoordinateInfo("t", (0.0, 1.0), 4), CoordinateInfo("a", (0.0, 1.0), 3, "linear"),
             CoordinateInfo("b", (0.0, 1.0), 5)]
    rng = np.random.default_rng(4)
    for field in (_train(rng, small, [3, 2], [2, 0, 1]), _train(rng, small, [2, 4], [0, 1, 2]), _cp(rng, small, 3)):
        index = np.stack(np.meshgrid(*[np.arange(c.nodes) for c in small], indexing="ij"), -1).reshape(-1, 3)
        rows = [np.eye(c.nodes)[index[:, j]] for j, c in enumerate(small)]
        np.testing.assert_allclose(field.evaluate(rows), field.full()[tuple(index.T)], rtol=1e-13, atol=1e-13)
    assert cb.fields["w"].shape == tuple(c.nodes for c in cb.coordinates)


def test_reference_is_a_product_of_matrices_point_by_point():
    rng = np.random.default_rng(5)
    cb = RANDOM["three orders side by side"]
    rows = value_rows(cb, nodal_points(cb, 7, 1))
    for field in cb.fields.values():
        for p in range(7):
            v = np.ones((1, 1))
            for core, j in zip(field.cores, field.mode_order):
                v = v @ sum(rows[j][p, i] * core[:, i, :] for i in range(core.shape[1]))
            assert field.evaluate([r[p:p + 1] for r in rows])[0] == pytest.approx(v[0, 0], rel=1e-12, abs=1e-12)
    cp = _cp(rng, cb.coordinates, 3)
    expected = sum(cp.weights[r] * np.prod([rows[j][0] @ cp.factors[j][:, r] for j in range(len(rows))])
                   for r in range(3))
    assert cp.evaluate([r[:1] for r in rows])[0] == pytest.approx(expected, rel=1e-12)


def test_reference_names_a_bad_row_matrix():
    field = RANDOM["every kind, time first"].fields["u"]
    rows = value_rows(RANDOM["every kind, time first"], nodal_points(RANDOM["every kind, time first"], 3, 2))
    with pytest.raises(ValueError, match="5 row matrices for a tensor train of order 6"):
        field.evaluate(rows[:5])
    rows[2] = rows[2][:, :-1]
    with pytest.raises(ValueError, match=r"row matrix 2 has shape \(3, 39\), expected \(P, 40\)"):
        field.evaluate(rows)


# ----------------------------------------------------------------------------------------------
# the fast paths
# ----------------------------------------------------------------------------------------------
def test_one_point(book):
    points = nodal_points(book, 25, 3)
    for i in range(25):
        point = {k: float(v[i]) for k, v in points.items()}
        rows = value_rows(book, {k: [v] for k, v in point.items()})
        every = book(**point)
        for u, field in book.fields.items():
            assert_agrees(every[u], field, rows, f"{u} at {point}")
            assert_agrees(book.evaluate(point, fields=[u])[u], field, rows, f"{u} alone at {point}")


@pytest.mark.parametrize("size", [2, 37, 3000])
def test_batch(book, size):
    points = nodal_points(book, size, size)
    rows = value_rows(book, points)
    values = book(**points)
    for u, field in book.fields.items():
        assert_agrees(values[u], field, rows, u)


def test_batch_grouped_by_every_later_window(book, monkeypatch):
    """The batch's cost model off: points grouped by every later coordinate of several windows."""
    monkeypatch.setattr(batch_eval, "SECONDS_PER_BLOCK", 0.0)
    cb = Codebook(book.coordinates, book.fields, name=book.name)
    points = nodal_points(cb, 2000, 9)
    rows = value_rows(cb, points)
    values = cb(**points)
    for u, field in cb.fields.items():
        assert_agrees(values[u], field, rows, u)


def test_series(book):
    along = book.coordinate_names[0]
    count = 9 if len(book.coordinates) > 1 else 1  # no other coordinate: one series
    points = nodal_points(book, count, 4)
    times = nodal_points(book, 31, 5)[along]
    series = book.evaluate_series({k: v for k, v in points.items() if k != along}, {along: times})
    outer = {k: np.repeat(v, times.size) for k, v in points.items()}
    outer[along] = np.tile(times, count)
    rows = value_rows(book, outer)
    for u, field in book.fields.items():
        assert series[u].shape == (count, 31)
        assert_agrees(series[u], field, rows, u)


def _grid(book, seed: int) -> tuple[dict, dict]:
    sizes = ([7, 5, 3, 4, 3, 2] + [2] * len(book.coordinates))[: len(book.coordinates)]
    axes = {c.name: nodal_points(book, n, seed + j)[c.name] for j, (c, n) in enumerate(zip(book.coordinates, sizes))}
    mesh = np.meshgrid(*axes.values(), indexing="ij")
    return axes, {name: m.reshape(-1) for name, m in zip(axes, mesh)}


def test_grid(book):
    axes, flat = _grid(book, 6)
    grid = book.evaluate_grid(axes)
    rows = value_rows(book, flat)
    for u, field in book.fields.items():
        assert grid[u].shape == tuple(a.size for a in axes.values())
        assert_agrees(grid[u], field, rows, u)


def test_gradient_at_points(book):
    points = nodal_points(book, 300, 7)
    gradient = book.gradient(points)
    for j, c in enumerate(book.coordinates):
        rows = derivative_rows(book, points, j)
        for u, field in book.fields.items():
            assert_agrees(gradient[u][c.name], field, rows, f"d{u}/d{c.name}")


def test_gradient_on_a_grid(book):
    axes, flat = _grid(book, 8)
    gradient = book.gradient(axes, grid=True)
    for j, c in enumerate(book.coordinates):
        rows = derivative_rows(book, flat, j)
        for u, field in book.fields.items():
            assert_agrees(gradient[u][c.name], field, rows, f"d{u}/d{c.name}")


def test_trajectory_model(book):
    """Values and derivatives along the first coordinate at a few points of the others (the fit's model)."""
    axis = book.coordinate_names[0]
    times = nodal_points(book, 40, 10)[axis]
    model = TrajectoryModel(book, axis, times, book.unknown_names)
    wrt = list(range(1, len(book.coordinates)))
    for i, point in enumerate(zip(*nodal_points(book, 4, 11).values())):
        out = model.evaluate(point, wrt)
        at = {c.name: np.full(times.size, point[j]) for j, c in enumerate(book.coordinates)}
        at[axis] = times
        for k, (u, field) in enumerate(book.fields.items()):
            assert_agrees(out[k, :, 0], field, value_rows(book, at), f"{u} at point {i}")
            for slot, j in enumerate(wrt, start=1):
                assert_agrees(out[k, :, slot], field, derivative_rows(book, at, j), f"d{u}/d{j} at point {i}")
