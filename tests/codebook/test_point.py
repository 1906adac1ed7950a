"""The one-point path (pgdcli.codebook.point.TTStack): its tail cache, merged end cores, one buffer.

The tail (every core after the first, or after the merged first two) is contracted once per
distinct set of tail values; these tests check the cached values against a plain einsum
contraction and against a fresh codebook (no cache), and that the cache never hides an error.
"""

from __future__ import annotations

import mmap

import numpy as np
import pytest

from pgdcli.codebook import point as point_module
from pgdcli.codebook.codebook import Codebook, CoordinateInfo, TT
from pgdcli.errors import QueryError
from pgdcli.pages import HUGE_PAGE


def _codebook(order=(0, 1, 2, 3)):
    coords = [CoordinateInfo("t", (0.0, 2.0), 9, "chebyshev", "time", breakpoints=(0.0, 0.8, 2.0)),
              CoordinateInfo("a", (-1.0, 1.0), 6, "chebyshev"),
              CoordinateInfo("b", (0.5, 1.5), 5, "linear"),
              CoordinateInfo("c", (1.0, 3.0), 7, "chebyshev")]
    rng = np.random.default_rng(31)
    fields = {}
    for name, ranks in (("u", (1, 8, 11, 5, 1)), ("w", (1, 6, 9, 4, 1))):
        fields[name] = TT(tuple(rng.standard_normal((ranks[k], coords[j].nodes, ranks[k + 1]))
                                     for k, j in enumerate(order)), order)
    return Codebook(coords, fields, name="series", report={})


def _plain(cb, point):
    out = {}
    for u, fm in cb.fields.items():
        v = np.ones(1)
        for core, j in zip(fm.cores, fm.mode_order):
            c = cb.coordinates[j]
            v = np.einsum("r,rns,n->s", v, core, c.basis().interpolation_matrix([point[c.name]])[0])
        out[u] = float(v[0])
    return out


@pytest.mark.parametrize("order", [(0, 1, 2, 3), (2, 0, 3, 1)], ids=str)
def test_time_series_at_fixed_parameters_matches_plain_contraction(order):
    cb = _codebook(order)
    rng = np.random.default_rng(32)
    for _ in range(4):
        params = {"a": float(rng.uniform(-1, 1)), "b": float(rng.uniform(0.5, 1.5)), "c": float(rng.uniform(1, 3))}
        times = [*rng.uniform(0.0, 2.0, 20), 0.0, 0.8, 2.0]
        for t in times:
            point = {"t": float(t), **params}
            one = cb(**point)
            fresh = _codebook(order)(**point)  # no cache
            plain = _plain(cb, point)
            for u in cb.unknown_names:
                assert abs(float(one[u]) - plain[u]) <= 1e-13 * max(1.0, abs(plain[u])), (point, u)
                assert float(one[u]) == float(fresh[u])  # the cached tail is the one a fresh query computes


def test_cache_changes_with_every_tail_value_and_never_hides_an_error():
    cb = _codebook()
    base = {"t": 0.3, "a": 0.2, "b": 0.9, "c": 2.2}
    cb(**base)
    for name, value in (("a", -0.4), ("b", 1.3), ("c", 1.1)):  # one tail value changes: a new contraction
        point = {**base, name: value}
        plain = _plain(cb, point)
        assert float(cb(**point)["u"]) == pytest.approx(plain["u"], rel=1e-13, abs=1e-13)
    cb(**base)
    with pytest.raises(QueryError, match=r"coordinate 't': value 2\.5 is outside the domain"):
        cb(**{**base, "t": 2.5})  # the head coordinate is checked on a cache hit
    with pytest.raises(QueryError, match=r"coordinate 't': value nan is outside"):
        cb(**{**base, "t": float("nan"), "c": 9.0})  # first bad coordinate in codebook order, as before
    with pytest.raises(QueryError, match=r"coordinate 'c': value 9\.0 is outside"):
        cb(**{**base, "c": 9.0})
    assert float(cb(**base)["w"]) == pytest.approx(_plain(cb, base)["w"], rel=1e-13, abs=1e-13)


# ----------------------------------------------------------------------------------------------
# both ends merged (the tail's last two cores as one table), a vector-first core between, one buffer
# ----------------------------------------------------------------------------------------------
def _five(arena_above=None, monkeypatch=None):
    """t (two slabs), a, b (Chebyshev), c (linear), d (Chebyshev, 4 nodes): the head pair (t, a), the
    tail pair (d, c) and b's core (2 x 50 x 48 slice values per node) contracted vector first."""
    if arena_above is not None:
        monkeypatch.setattr(point_module, "HUGE_PAGES_ABOVE", arena_above)
    coords = [CoordinateInfo("t", (0.0, 2.0), 9, "chebyshev", "time", breakpoints=(0.0, 0.8, 2.0)),
              CoordinateInfo("a", (-1.0, 1.0), 6, "chebyshev"),
              CoordinateInfo("b", (0.5, 1.5), 7, "chebyshev"),
              CoordinateInfo("c", (1.0, 3.0), 5, "linear"),
              CoordinateInfo("d", (-2.0, 0.0), 4, "chebyshev")]
    rng = np.random.default_rng(33)
    fields = {}
    for name, ranks in (("u", (1, 8, 50, 48, 6, 1)), ("w", (1, 6, 40, 45, 5, 1))):
        fields[name] = TT(tuple(rng.standard_normal((ranks[k], c.nodes, ranks[k + 1])) / np.sqrt(ranks[k])
                                     for k, c in enumerate(coords)), (0, 1, 2, 3, 4))
    return Codebook(coords, fields, name="five", report={})


def _five_points(cb, count=30):
    rng = np.random.default_rng(34)
    out = []
    for k in range(count):
        point = {}
        for c in cb.coordinates:
            nodes = c.basis().nodes
            choices = [float(rng.uniform(*c.domain)), float(nodes[1]), c.domain[0], c.domain[1],
                       *c.breakpoints[1:-1]]
            point[c.name] = choices[0] if k < 10 else choices[int(rng.integers(len(choices)))]
        out.append(point)
    return out


def test_both_ends_merged_and_a_vector_first_core_match_the_plain_contraction():
    cb = _five()
    stack = cb._tt_stack
    assert stack.pair is not None and stack.tail_pair is not None
    assert [through_table for _, through_table, *_ in stack.tail] == [False]  # b, between the pairs
    for point in _five_points(cb):
        one, plain, fresh = cb(**point), _plain(cb, point), _five()(**point)
        batch = cb(**{k: np.array([v, v]) for k, v in point.items()})
        for u in cb.unknown_names:
            scale = max(1.0, abs(plain[u]))
            assert abs(float(one[u]) - plain[u]) <= 1e-13 * scale, (point, u)
            assert abs(float(one[u]) - batch[u][0]) <= 1e-13 * scale, (point, u)
            assert float(one[u]) == float(fresh[u])  # a cached tail is the one a fresh query computes


def test_tables_in_one_huge_page_buffer_give_the_same_values_bitwise(monkeypatch):
    plain_memory = _five()
    one_buffer = _five(arena_above=0, monkeypatch=monkeypatch)
    table = one_buffer._tt_stack.pair[2]
    if hasattr(mmap, "MADV_HUGEPAGE"):
        assert table.ctypes.data % HUGE_PAGE == 0  # the first table opens the mapping
        windows = [w for *_, windows, _ in one_buffer._tt_stack.tail for w, *_ in windows]
        assert all(w.ctypes.data > table.ctypes.data for w in windows)  # carved after it
    for point in _five_points(plain_memory, 12):
        a, b = plain_memory(**point), one_buffer(**point)
        assert all(float(a[u]) == float(b[u]) for u in a)


def test_an_arena_that_runs_out_hands_out_ordinary_arrays(monkeypatch):
    monkeypatch.setattr(point_module, "HUGE_PAGES_ABOVE", 0)
    arena = point_module._Arena(10)
    inside, outside = arena.empty((2, 3)), arena.empty((5,))
    assert inside.base is not None and outside.base is None
    assert inside.shape == (2, 3) and outside.shape == (5,)
    assert arena.empty((4,)).base is not None  # the 4 values left
