"""The checks every query goes through: names, unknowns, values inside the domain."""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.codebook.domain import check_names, clip_to_domain, domain_slack, select_fields
from pgdcli.discretization.coordinates import CoordinateInfo
from pgdcli.errors import QueryError


def _coordinate(name="k", domain=(0.5, 2.0)):
    return CoordinateInfo(name, domain, 5)


def test_values_a_rounding_outside_are_clipped_onto_the_boundary():
    c = _coordinate()
    x = np.array([0.5 - 1e-14, 1.0, 2.0 + 1e-13])
    assert clip_to_domain(c, x).tolist() == [0.5, 1.0, 2.0]


def test_a_value_beyond_the_slack_is_named():
    c = _coordinate()
    beyond = 2.0 + 10 * domain_slack(0.5, 2.0)
    with pytest.raises(QueryError, match=r"coordinate 'k': value 2\.00000000002 is outside the domain \[0\.5, 2\]"):
        clip_to_domain(c, np.array([1.0, beyond]))


def test_nan_is_outside_every_domain():
    with pytest.raises(QueryError, match="value nan is outside"):
        clip_to_domain(_coordinate(), np.array([np.nan]))


def test_the_slack_scales_with_the_domain():
    assert domain_slack(0.0, 1.0) == 1e-12
    assert domain_slack(-1e6, 3.0) == pytest.approx(1e-6)


def test_unknown_names_come_before_missing_ones():
    coords = [_coordinate("t", (0, 1)), _coordinate("k")]
    with pytest.raises(QueryError, match="unknown coordinate 'q'; this codebook has t, k"):
        check_names(coords, {"q": 1.0})
    with pytest.raises(QueryError, match=r"missing coordinate 'k' \(domain \[0\.5, 2\]\)"):
        check_names(coords, {"t": 1.0})
    check_names(coords, {"k": 1.0, "t": 0.0})


def test_fields_are_selected_in_the_order_asked():
    assert select_fields(["u", "v"], None) == ["u", "v"]
    assert select_fields(["u", "v"], ["v", "u"]) == ["v", "u"]
    with pytest.raises(QueryError, match="unknown field 'w'; this codebook has u, v"):
        select_fields(["u", "v"], ["w"])
