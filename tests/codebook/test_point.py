"""The one-point path's tail cache (pgdcli.codebook.point.TTStack): a time series at fixed parameters.

The tail (every core after the first, or after the merged first two) is contracted once per
distinct set of tail values; these tests check the cached values against a plain einsum
contraction and against a fresh codebook (no cache), and that the cache never hides an error.
"""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.codebook.codebook import Codebook, CoordinateInfo, FieldTT
from pgdcli.errors import QueryError


def _codebook(order=(0, 1, 2, 3)):
    coords = [CoordinateInfo("t", (0.0, 2.0), 9, "chebyshev", "time", breakpoints=(0.0, 0.8, 2.0)),
              CoordinateInfo("a", (-1.0, 1.0), 6, "chebyshev"),
              CoordinateInfo("b", (0.5, 1.5), 5, "linear"),
              CoordinateInfo("c", (1.0, 3.0), 7, "chebyshev")]
    rng = np.random.default_rng(31)
    fields = {}
    for name, ranks in (("u", (1, 8, 11, 5, 1)), ("w", (1, 6, 9, 4, 1))):
        fields[name] = FieldTT(tuple(rng.standard_normal((ranks[k], coords[j].nodes, ranks[k + 1]))
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
