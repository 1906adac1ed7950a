"""Codebook.evaluate_series (pgdcli.codebook.series) against Codebook.evaluate on the flattened points.

``evaluate`` on the broadcast ``(S, T)`` points takes another algorithm (the batch path:
tensor trains block by block from the first core, CP chunk by chunk), so agreement to
rounding checks the series' contraction from both ends toward the series core. Codebooks:
hand-made tensor trains with the series coordinate first (time slabs), in the middle and
last of the core order, linear elements, a CP field beside a train, a one-coordinate
codebook, and the shipped coupled march codebook; points on nodes, breakpoints and domain ends.
"""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.codebook.codebook import Codebook, CoordinateInfo, CPTensor, TT
from pgdcli.errors import QueryError


def _random_tt(rng, coords, ranks, order):
    full = [1] + ranks + [1]
    cores = tuple(rng.standard_normal((full[k], coords[j].nodes, full[k + 1])) / np.sqrt(full[k] * coords[j].nodes)
                  for k, j in enumerate(order))
    return TT(cores, tuple(order))


def _books() -> dict[str, Codebook]:
    rng = np.random.default_rng(21)
    t = CoordinateInfo("t", (0.0, 2.0), 5 * 6 + 1, "chebyshev", "time", (0.0, 0.3, 0.7, 1.1, 1.6, 2.0))
    a = CoordinateInfo("a", (-1.0, 2.0), 9)
    b = CoordinateInfo("b", (0.0, 1.0), 11, "linear")
    c = CoordinateInfo("c", (0.5, 1.5), 6)
    coords = [t, a, b, c]
    cp = CPTensor(rng.standard_normal(4), tuple(rng.standard_normal((ci.nodes, 4)) for ci in coords))
    return {
        "time first": Codebook(coords, {"u": _random_tt(rng, coords, [10, 14, 5], [0, 1, 2, 3]),
                                        "v": _random_tt(rng, coords, [3, 8, 4], [0, 1, 2, 3])}),
        "time in the middle, CP beside": Codebook(coords, {"u": _random_tt(rng, coords, [5, 13, 6], [1, 2, 0, 3]),
                                                           "p": cp}),
        "time last": Codebook(coords, {"u": _random_tt(rng, coords, [4, 12, 6], [2, 1, 3, 0])}),
        "CP only": Codebook(coords, {"p": cp}),
        "linear time": Codebook([b, a, c], {"u": _random_tt(rng, [b, a, c], [7, 5], [0, 1, 2])}),
        "one coordinate": Codebook([t], {"u": TT((rng.standard_normal((1, t.nodes, 1)),), (0,))}),
        "many time slabs, CP beside": _many_slabs(rng, a, c),
    }


def _many_slabs(rng, a: CoordinateInfo, c: CoordinateInfo) -> Codebook:
    """A march's time basis: 40 slabs of 5 nodes, its series rows applied slab by slab (SlabRows)."""
    t = CoordinateInfo("t", (0.0, 2.0), 40 * 4 + 1, "chebyshev", "time", tuple(np.linspace(0.0, 2.0, 41)))
    coords = [t, a, c]
    cp = CPTensor(rng.standard_normal(3), tuple(rng.standard_normal((ci.nodes, 3)) for ci in coords))
    return Codebook(coords, {"u": _random_tt(rng, coords, [6, 5], [1, 0, 2]), "p": cp})


BOOKS = _books()


def _special(rng, c: CoordinateInfo, basis, size: int) -> np.ndarray:
    """Uniform values, a third of them on nodes (breakpoints, ends included), both ends present."""
    x = rng.uniform(*c.domain, size)
    hit = rng.random(size) < 1 / 3
    x[hit] = basis.nodes[rng.integers(0, basis.nodes.size, int(hit.sum()))]
    x[:2] = c.domain[:size]
    return x


def _check(cb: Codebook, along: str, samples: int, times: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    bases = dict(zip(cb.coordinate_names, cb._bases))
    points = {c.name: _special(rng, c, bases[c.name], samples) for c in cb.coordinates if c.name != along}
    series = _special(rng, cb.coordinate(along), bases[along], times)
    ours = cb.evaluate_series(points, {along: series})
    flat = cb.evaluate({along: series[None, :]} | {n: v[:, None] for n, v in points.items()})
    for u in cb.unknown_names:
        want = np.broadcast_to(flat[u], (max(samples, 1) if points else 1, times))
        assert ours[u].shape == want.shape
        scale = max(1.0, float(np.max(np.abs(want))) if want.size else 1.0)
        np.testing.assert_allclose(ours[u], want, rtol=0, atol=5e-14 * scale, err_msg=u)


@pytest.mark.parametrize("name", sorted(BOOKS))
def test_series_equals_evaluate_on_the_flattened_points(name):
    cb = BOOKS[name]
    along = cb.coordinate_names[0] if name != "linear time" else "b"
    for samples, times in ((1, 1), (3, 40), (57, 9)):
        _check(cb, along, samples, times, seed=samples)


def test_many_time_slabs_take_the_slab_rows():
    from pgdcli.discretization.basis import SlabRows

    cb = BOOKS["many time slabs, CP beside"]
    assert isinstance(cb.coordinate("t").basis().series_rows(np.linspace(0.0, 2.0, 7)), SlabRows)
    assert isinstance(BOOKS["time first"].coordinate("t").basis().series_rows(np.linspace(0.0, 2.0, 7)), np.ndarray)


def test_series_along_a_parameter_coordinate():
    """Any coordinate can be the series: here a parameter, the time among the points."""
    _check(BOOKS["time first"], "a", 23, 17, seed=4)
    _check(BOOKS["time in the middle, CP beside"], "c", 5, 12, seed=5)


def test_march_codebook(solved):
    cb = solved("coupled").codebook
    _check(cb, "t", 40, 99, seed=6)


def test_scalars_empty_and_selection():
    cb = BOOKS["time in the middle, CP beside"]
    one = cb.evaluate_series({"a": 0.5, "b": 0.25, "c": 1.0}, {"t": [0.0, 0.3, 1.9]}, fields=["p"])
    assert list(one) == ["p"] and one["p"].shape == (1, 3)
    flat = cb.evaluate({"t": np.array([0.0, 0.3, 1.9]), "a": 0.5, "b": 0.25, "c": 1.0}, fields=["p"])
    np.testing.assert_allclose(one["p"][0], flat["p"], rtol=0, atol=5e-14 * max(1.0, np.max(np.abs(flat["p"]))))
    none = cb.evaluate_series({"a": np.empty(0), "b": np.empty(0), "c": np.empty(0)}, {"t": [0.5]})
    assert none["u"].shape == (0, 1) and none["p"].shape == (0, 1)
    assert cb.evaluate_series({"a": [0.0, 1.0], "b": 0.5, "c": 1.0}, {"t": []})["u"].shape == (2, 0)


@pytest.mark.parametrize("points, series, message", [
    ({"a": 0.0, "b": 0.5, "c": 1.0}, {}, "one coordinate"),
    ({"a": 0.0, "b": 0.5}, {"t": [0.0], "c": [1.0]}, "one coordinate"),
    ({"a": 0.0, "b": 0.5}, {"t": [0.0]}, "missing coordinate 'c'"),
    ({"a": 0.0, "b": 0.5, "c": 1.0, "z": 1.0}, {"t": [0.0]}, "unknown coordinate 'z'"),
    ({"a": 0.0, "b": 0.5, "c": 1.0, "t": 1.0}, {"t": [0.0]}, "both"),
    ({"a": 0.0, "b": 0.5, "c": 1.0}, {"t": [0.0, 2.5]}, "outside the domain"),
    ({"a": [0.0, 9.0], "b": 0.5, "c": 1.0}, {"t": [0.0]}, "outside the domain"),
    ({"a": 0.0, "b": 0.5, "c": 1.0}, {"t": [[0.0]]}, "1-D"),
])
def test_bad_queries(points, series, message):
    with pytest.raises(QueryError, match=message):
        BOOKS["time first"].evaluate_series(points, series)


def test_check_values_at_samples_use_the_series(solved):
    """pgdcli.checks.compare.codebook_at_samples (the error gate's codebook side): the series, and
    the old broadcast evaluation, agree; a codebook without the time coordinate repeats its values."""
    from pgdcli.checks.compare import codebook_at_samples

    cb = solved("coupled").codebook
    rng = np.random.default_rng(8)
    samples = {c.name: rng.uniform(*c.domain, 30) for c in cb.coordinates if c.name != "t"}
    times = np.linspace(0.0, 0.5, 21)
    ours = codebook_at_samples(cb, samples, "t", times, ["u2", "u1"])
    flat = cb.evaluate({"t": times[None, :]} | {n: v[:, None] for n, v in samples.items()}, fields=["u2", "u1"])
    assert list(ours) == ["u2", "u1"]
    for u in ours:
        np.testing.assert_allclose(ours[u], flat[u], rtol=0, atol=5e-14 * max(1.0, np.max(np.abs(flat[u]))))
    steady = BOOKS["CP only"]
    points = {c.name: rng.uniform(*c.domain, 4) for c in steady.coordinates}
    got = codebook_at_samples(steady, points, None, np.zeros(3), ["p"])["p"]
    assert got.shape == (4, 3) and np.array_equal(got, np.repeat(steady.evaluate(points)["p"][:, None], 3, axis=1))
