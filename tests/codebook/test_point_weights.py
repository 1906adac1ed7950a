"""One point's weights (pgdcli.codebook.point_weights): grouped Chebyshev coordinates, node hits, domain errors.

The weights of a group of plain Chebyshev coordinates are computed as one array; these tests
check them against each coordinate's basis (its interpolation matrix, independent of the
one-point code) and bit for bit against the coordinate-by-coordinate weights.
"""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.codebook.codebook import CoordinateInfo
from pgdcli.codebook.point_weights import PointData, PointWeights
from pgdcli.errors import QueryError

COORDS = [CoordinateInfo("t", (0.0, 2.0), 9, "chebyshev", "time", breakpoints=(0.0, 0.8, 2.0)),
          CoordinateInfo("a", (-1.0, 1.0), 6, "chebyshev"),
          CoordinateInfo("b", (0.5, 1.5), 5, "linear"),
          CoordinateInfo("c", (1.0, 3.0), 6, "chebyshev"),
          CoordinateInfo("d", (0.0, 1.0), 7, "chebyshev"),
          CoordinateInfo("e", (2.0, 4.0), 7, "chebyshev"),
          CoordinateInfo("f", (-3.0, -2.0), 6, "chebyshev")]


def _points(coords=COORDS):
    return [PointData(c, c.basis(), np.zeros((c.nodes, 1))) for c in coords]


def _row(point: PointData, k: int, c) -> np.ndarray:
    """The cardinal row on all nodes that the weights ``(k, c)`` stand for."""
    row = np.zeros(point.nodes.size)
    if c is None:
        row[k] = 1.0
        return row
    lo, hi = point.window_bounds()[k]
    row[lo:hi] = c / c.sum()
    return row


def test_groups_are_the_plain_chebyshev_coordinates_of_one_node_count():
    weights = PointWeights(_points())
    assert sorted(sorted(members) for members, *_ in weights.groups) == [[1, 3, 6], [4, 5]]
    assert weights.alone == [0, 2]  # the piecewise time coordinate and the linear one


def test_rows_match_each_basis_and_the_coordinate_by_coordinate_weights_bitwise():
    points = _points()
    weights = PointWeights(points)
    rng = np.random.default_rng(5)
    for _ in range(200):
        xs = [float(rng.uniform(*c.domain)) for c in COORDS]
        got = weights(xs)
        for x, c, p, (k, w) in zip(xs, COORDS, points, got):
            expected = c.basis().interpolation_matrix(np.array([x]))[0]
            np.testing.assert_allclose(_row(p, k, w), expected, rtol=0, atol=1e-14)
            k1, w1 = p.weights(p.clipped(x))
            assert k == k1 and np.array_equal(w, w1)


@pytest.mark.parametrize("member", [1, 3, 6])
def test_a_node_of_one_group_member_gives_its_unit_row_and_the_others_their_weights(member):
    points = _points()
    weights = PointWeights(points)
    xs = [0.3, 0.1, 0.9, 1.7, 0.4, 3.1, -2.6]
    xs[member] = float(points[member].nodes[2])
    got = weights(xs)
    assert got[member] == (2, None)
    for j in (1, 3, 6):
        expected = COORDS[j].basis().interpolation_matrix(np.array([xs[j]]))[0]
        np.testing.assert_allclose(_row(points[j], *got[j]), expected, rtol=0, atol=1e-14)


def test_values_within_the_slack_are_clipped_as_the_batch_path_clips_them():
    points = _points()
    got = PointWeights(points)([0.3, -1.0 - 1e-13, 0.9, 3.0 + 1e-13, 0.4, 3.1, -2.6])
    assert got[1] == (int(np.argmin(points[1].nodes)), None)  # -1 is a node: clipped onto it
    assert got[3] == (int(np.argmax(points[3].nodes)), None)


def test_the_first_coordinate_outside_its_domain_is_named_even_before_a_group_member():
    weights = PointWeights(_points())
    with pytest.raises(QueryError, match=r"coordinate 'b': value 2\.0 is outside the domain \[0\.5, 1\.5\]"):
        weights([0.3, 0.1, 2.0, 9.0, 0.4, 3.1, -2.6])  # 'c' (a group member) is outside too
    with pytest.raises(QueryError, match=r"coordinate 'a'"):
        weights([0.3, 5.0, 0.9, 9.0, 0.4, 3.1, -2.6])
    with pytest.raises(QueryError, match=r"coordinate 'f': value nan"):
        weights([0.3, 0.1, 0.9, 1.7, 0.4, 3.1, float("nan")])
