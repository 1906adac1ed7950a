"""The tensor-train batch path (pgdcli.codebook.batch_eval) against an independent contraction.

The reference here contracts each point on its own: the dense cardinal row of every
coordinate (``basis.interpolation_matrix``, all nodes) times each core, left to right
in the train's order, with ``numpy.einsum``. Codebooks: the shipped march problems
(time slabs, the first two cores merged per slab), and hand-made trains with every
kind of first coordinate (one Chebyshev window, slabs narrower and wider than the
first bond, linear elements), unknowns in different core orders, and points on
nodes, breakpoints and the domain's ends.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import nodal_points

import pgdcli.codebook.point as point_module
import pgdcli.codebook.threads as threads_module
from pgdcli.codebook.batch_eval import TTBatch, _window_of
from pgdcli.discretization.basis import make_basis
from pgdcli.codebook.codebook import Codebook, CoordinateInfo, CPTensor, TT


def _reference(cb: Codebook, points: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Every tensor-train unknown at each point, one point at a time (dense rows, einsum)."""
    rows = [b.interpolation_matrix(np.clip(points[c.name], *c.domain)) for c, b in zip(cb.coordinates, cb._bases)]
    out = {}
    for u, f in cb.fields.items():
        if not isinstance(f, TT):
            continue
        values = np.empty(rows[0].shape[0])
        for i in range(values.size):
            v = np.ones(1)
            for core, j in zip(f.cores, f.mode_order):
                v = np.einsum("a,anb,n->b", v, core, rows[j][i])
            values[i] = v[0]
        out[u] = values
    return out


def _assert_close(ours: dict, ref: dict) -> None:
    for u, v in ref.items():
        scale = max(1.0, float(np.max(np.abs(v))))
        np.testing.assert_allclose(ours[u], v, rtol=0, atol=5e-14 * scale, err_msg=u)


def _random_tt(rng, coords: list[CoordinateInfo], ranks: list[int], order: list[int]) -> TT:
    full = [1] + ranks + [1]
    cores = tuple(rng.standard_normal((full[k], coords[j].nodes, full[k + 1])) / np.sqrt(full[k] * coords[j].nodes)
                  for k, j in enumerate(order))
    return TT(cores, tuple(order))


def _slab_time(name: str, slabs: int, per_slab: int, domain=(0.0, 2.0)) -> CoordinateInfo:
    breaks = tuple(np.linspace(*domain, slabs + 1) ** 1.3 / domain[1] ** 0.3)  # uneven slabs
    return CoordinateInfo(name, domain, slabs * (per_slab - 1) + 1, "chebyshev", "time", breaks)


def _hand_made() -> dict[str, Codebook]:
    rng = np.random.default_rng(3)
    t = _slab_time("t", 5, 7)
    a = CoordinateInfo("a", (-1.0, 2.0), 9)
    b = CoordinateInfo("b", (0.0, 1.0), 11, "linear")
    c = CoordinateInfo("c", (0.5, 1.5), 6)
    coords = [t, a, b, c]
    books = {
        # slab window (7) narrower than the first bond (10): first two cores merged per slab
        "slabs, merged pair": {"u": _random_tt(rng, coords, [10, 14, 5], [0, 1, 2, 3]),
                               "v": _random_tt(rng, coords, [12, 9, 4], [0, 1, 2, 3])},
        # merged pairs whose second coordinate is a whole linear basis (11 nodes), and whose
        # first is one Chebyshev window (6 nodes) narrower than the first bond (7)
        "merged pair, linear second": {"u": _random_tt(rng, coords, [9, 8, 4], [0, 2, 1, 3])},
        "merged pair, one window": {"u": _random_tt(rng, coords, [7, 12, 5], [3, 1, 0, 2])},
        # window (7) wider than the first bond (3): the first core by windows, no merge
        "slabs, no merge": {"u": _random_tt(rng, coords, [3, 8, 4], [0, 1, 2, 3])},
        # one Chebyshev window first; a linear coordinate later
        "chebyshev first": {"u": _random_tt(rng, coords, [5, 13, 6], [1, 0, 2, 3])},
        # linear elements first (windows of two nodes), and two core orders side by side
        "linear first, two orders": {"u": _random_tt(rng, coords, [4, 12, 6], [2, 1, 0, 3]),
                                     "v": _random_tt(rng, coords, [6, 10, 3], [0, 3, 2, 1]),
                                     "w": _random_tt(rng, coords, [2, 7, 9], [2, 1, 0, 3])},
    }
    out = {name: Codebook(coords, fields, name=name) for name, fields in books.items()}
    # a tensor train beside CP unknowns (the mixed path) and a one-coordinate train
    cp = CPTensor(rng.standard_normal(3), tuple(rng.standard_normal((ci.nodes, 3)) for ci in coords))
    out["mixed with CP"] = Codebook(coords, {"p": cp, "u": _random_tt(rng, coords, [9, 11, 5], [0, 1, 2, 3])})
    out["one coordinate"] = Codebook([t], {"u": TT((rng.standard_normal((1, t.nodes, 1)),), (0,))})
    return out


HAND_MADE = _hand_made()


@pytest.mark.parametrize("name", sorted(HAND_MADE))
def test_batch_equals_pointwise_contraction_hand_made(name):
    cb = HAND_MADE[name]
    for size, seed in ((1, 1), (2, 2), (37, 3), (3000, 4)):  # one point, one block, many blocks and windows
        points = nodal_points(cb, size, seed)
        ours = cb(**points)
        _assert_close(ours, _reference(cb, points))


@pytest.mark.parametrize("name", sorted(HAND_MADE))
def test_batch_equals_one_point_path(name):
    """The batch path and the one-point path (a different algorithm: TTStack) agree."""
    cb = HAND_MADE[name]
    points = nodal_points(cb, 200, 11)
    batch = cb(**points)
    for i in range(0, 200, 7):
        one = cb(**{k: float(v[i]) for k, v in points.items()})
        for u in cb.unknown_names:
            assert abs(float(one[u]) - batch[u][i]) <= 5e-14 * max(1.0, abs(float(one[u]))), (u, i)


@pytest.mark.parametrize("name", ["coupled", "logistic"])
def test_batch_equals_pointwise_contraction_march_codebooks(solved, name):
    cb = solved(name).codebook
    points = nodal_points(cb, 1500, 5)
    _assert_close(cb(**points), _reference(cb, points))


def test_blocks_and_threads_never_change_a_value(solved, monkeypatch):
    """Blocks are cut from the sorted points the same way whatever the threads: bitwise equal."""
    cb = solved("coupled").codebook
    size = threads_module.PARALLEL_MIN_POINTS + 3000
    points = nodal_points(cb, size, 6)
    ref = cb(**points)
    for threads in (1, 2, 3):
        monkeypatch.setattr(threads_module, "available_threads", lambda: threads)
        other = cb(**points)
        for u in cb.unknown_names:
            assert other[u].tobytes() == ref[u].tobytes(), threads


@pytest.mark.parametrize("name", sorted(HAND_MADE))
def test_blocks_grouped_by_later_windows(name, monkeypatch):
    """Blocks made free let the batch group points by the windows of later coordinates too (the
    slab time and the linear coordinate where they are not first): each block then contracts
    only its windows' parts of those cores and pair tables. Against the independent contraction."""
    import pgdcli.codebook.batch_eval as batch_module

    monkeypatch.setattr(batch_module, "SECONDS_PER_BLOCK", 0.0)
    monkeypatch.setattr(batch_module, "MIN_BLOCK", 4)
    monkeypatch.setattr(batch_module, "BLOCK_BYTES", 64)
    cb = HAND_MADE[name]
    fields = {u: f for u, f in cb.fields.items() if isinstance(f, TT)}
    batch = TTBatch(fields, cb._bases)
    points = nodal_points(cb, 3000, 21)
    flat = [np.clip(points[c.name], *c.domain) for c in cb.coordinates]
    grouped = [j for train in batch.trains for j, _ in batch._group_key(train, flat)[1]]
    later = [j for train in batch.trains for j in train.later_windows]
    assert sorted(grouped) == sorted(later)  # every later windowed coordinate is grouped by here
    _assert_close(batch.evaluate(flat, list(fields)), _reference(cb, points))


@pytest.mark.parametrize("slabs", [2, 7, 33, 40])
def test_slab_windows_as_the_basis_finds_them(slabs):
    """Counted breakpoints (up to 32 interior ones) and the search beyond give the basis's own slabs,
    breakpoints (they go right) and the domain's ends included."""
    breaks = np.linspace(0.0, 2.0, slabs + 1) ** 1.5 / 2.0 ** 0.5
    basis = make_basis("chebyshev", (0.0, 2.0), slabs * 5 + 1, breakpoints=breaks)
    x = np.concatenate([np.random.default_rng(slabs).uniform(0.0, 2.0, 5000), breaks, basis.nodes])
    assert np.array_equal(_window_of(basis, x), basis.slab_of(x))


def test_selected_fields_and_shapes():
    cb = HAND_MADE["linear first, two orders"]
    rng = np.random.default_rng(12)
    grid = {"t": rng.uniform(0, 2, (4, 1)), "a": rng.uniform(-1, 2, (1, 5)), "b": 0.25, "c": 1.0}
    both = cb.evaluate(grid)
    only = cb.evaluate(grid, fields=["w", "u"])
    assert list(only) == ["w", "u"] and only["w"].shape == (4, 5)
    for u in ("w", "u"):
        assert only[u].tobytes() == both[u].tobytes()
    batch = TTBatch({u: cb.fields[u] for u in ("v",)}, cb._bases)
    flat = [np.full(3, 0.5), np.full(3, 0.0), np.full(3, 0.5), np.full(3, 1.0)]
    assert list(batch.evaluate(flat, ["v"])) == ["v"]
    assert batch.evaluate([np.empty(0)] * 4, ["v"])["v"].shape == (0,)
