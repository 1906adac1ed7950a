"""The automatic resolution's decision (pgdcli.adapt.next_nodes): given a measured error, the Chebyshev tails
and decay rates of a round, which coordinates get more nodes, and how many; and, end to end, that a problem
with one under-resolved parameter refines that coordinate only, checked against its exact solution.

The expected counts are worked out here from the geometric decay the decision assumes: an error ratio r
along a coordinate whose Chebyshev coefficients fall by exp(rate) per node reaches the target share s of
the tolerance at n + log(r / s) / rate nodes.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from conftest import spec_text
import pgdcli
from pgdcli import parse_spec
from pgdcli.adapt import ROOM, TARGET, next_nodes, total_nodes
from pgdcli.checks.resolution import MIN_GROWTH, error_estimates
from pgdcli.checks.check import CheckResult

#: 1-D heat whose diffusivity k moves the decay rate (many nodes in k) and whose boundary value g enters
#: linearly (the first nodes are exact): u = g x + exp(-k pi^2 t) sin(pi x).
HEAT = spec_text(
    name=' heat_k',
    coordinates={'x': '{domain: [0, 1]}', 't': '{domain: [0, 0.5]}', 'k': '{domain: [0.1, 2]}',
                 'g': '{domain: [0, 1]}'},
    unknowns={'u': '{initial: "g*x + sin(pi*x)", boundary: {x: {low: 0, high: g}}}'},
    equations=['"der(u) = k*der(u, x, 2)"'],
    solver={'tolerance': '1e-7'},
)

#: Relaxation to c / k: u = c / k + (1 - c / k) exp(-k t); c enters linearly.
RELAXATION = spec_text(
    name=' relaxation_k',
    coordinates={'t': '{domain: [0, 2]}', 'k': '{domain: [0.5, 5]}', 'c': '{domain: [0, 1]}'},
    unknowns={'u': '{initial: 1}'},
    equations=['"der(u) = -k*u + c"'],
    solver={'tolerance': '1e-8'},
)


def heat(**nodes):
    """The heat problem at the given node counts (automatic coordinates, as the resolution sets them)."""
    problem = parse_spec(HEAT, source="heat_k.yaml")
    coords = tuple(dataclasses.replace(c, nodes=nodes.get(c.name, c.nodes)) for c in problem.coordinates)
    return dataclasses.replace(problem, coordinates=coords)


def pde_check(ratio: float, tails: dict) -> CheckResult:
    """A method-of-lines check as the gate reports it: one measured ratio, the tails per coordinate."""
    return CheckResult(ratio * 1e-5, ratio * 1e-5, ratio * 1e-5, 12, 0, ratio=ratio, node_ratio=ratio,
                       between_ratio=ratio, tail_ratio=tails, tolerance=1e-5)


def nodes(problem) -> dict:
    return {c.name: total_nodes(c) for c in problem.coordinates}


def predicted(n: int, ratio: float, rate: float, share: float) -> int:
    return max(math.ceil(n + math.log(ratio / share) / rate), n + math.ceil(MIN_GROWTH * (n - 1)))


def test_a_discretization_limited_round_refines_only_the_coordinates_whose_tails_lack_nodes():
    problem = heat(x=17, t=33, g=9, k=9)
    check = pde_check(11.0, {"x": 1.9, "t": 5.7e-4, "g": 6.8e-8, "k": 1.0})
    decay = {"x": 0.412, "t": 0.341, "k": 0.846}
    refined, chosen, stuck = next_nodes(problem, check, decay, {}, limited=True)
    assert sorted(chosen) == ["k", "x"] and stuck == []
    # the tails (2.9 in all) explain the measured 11 only scaled up together; two coordinates share the room
    scale, share = 11.0 / 2.9, min(TARGET, ROOM / 2)
    assert nodes(refined) == {"x": predicted(17, 1.9 * scale, 0.412, share), "t": 33, "g": 9,
                              "k": predicted(9, 1.0 * scale, 0.846, share)}
    assert nodes(refined)["x"] < 33 and nodes(refined)["k"] < 17  # less than the doubling


def test_a_limited_round_whose_tails_show_nothing_refines_all_of_time_and_space():
    problem = heat(x=17, t=33, g=9, k=9)
    check = pde_check(3.0, {"x": 1e-3, "t": 1e-3, "g": 1e-8, "k": 1e-3})
    refined, chosen, _ = next_nodes(problem, check, {}, {}, limited=True)
    assert sorted(chosen) == ["t", "x"]
    assert nodes(refined) == {"x": 33, "t": 65, "g": 9, "k": 9}  # no rate to go by: doubled


def test_a_limited_round_refines_the_parameter_with_the_largest_tail_when_no_tail_is_large():
    """The check of a PDE measures the error as a whole: a parameter's error off its nodes is in it, and its
    tail (an RMS over the other coordinates) can be small beside a local error there."""
    problem = heat(x=17, t=33, g=9, k=24)
    check = pde_check(2.7, {"x": 0.017, "t": 0.02, "g": 1e-9, "k": 0.25})
    refined, chosen, _ = next_nodes(problem, check, {"x": 1.15, "t": 0.5, "k": 0.53}, {}, limited=True)
    assert chosen == ["k"]
    assert nodes(refined) == {"x": 17, "t": 33, "g": 9, "k": predicted(24, 2.7, 0.53, TARGET)}


def test_a_time_coordinate_with_a_moderate_tail_is_refined_in_a_limited_round():
    problem = heat(x=17, t=33, g=9, k=9)
    check = pde_check(3.0, {"x": 2.0, "t": 0.1, "g": 0.0, "k": 0.0})
    _, chosen, _ = next_nodes(problem, check, {"x": 0.4, "t": 0.3}, {}, limited=True)
    assert sorted(chosen) == ["t", "x"]
    # not limited (a solver stopped short, say): only the coordinate whose tail is a large share
    _, chosen, _ = next_nodes(problem, check, {"x": 0.4, "t": 0.3}, {})
    assert chosen == ["x"]


def test_measured_off_node_errors_decide_and_a_slow_spectrum_doubles():
    problem = heat(x=17, t=33, g=9, k=9)
    check = CheckResult(4e-4, 1e-7, 4e-4, 100, 0, ratio=40.0, node_ratio=0.01, between_ratio=40.0,
                        coordinate_ratio={"g": 0.2, "k": 40.0}, tail_ratio={"k": 5.0}, tolerance=1e-5)
    refined, chosen, _ = next_nodes(problem, check, {"k": 0.9}, {})
    assert chosen == ["k"]
    assert nodes(refined)["k"] == predicted(9, 40.0, 0.9, TARGET)  # the measured ratio, not the tail
    history = {}
    refined, _, _ = next_nodes(problem, check, {"k": 0.1}, history)  # slower than MIN_DECAY: not trusted
    assert nodes(refined)["k"] == 17 and history["k"] == [("p", 40.0, 9, 9, 0)]


def test_a_later_refinement_goes_by_the_decay_measured_over_the_last():
    problem = heat(x=17, t=33, g=9, k=17)
    check = CheckResult(1e-4, 1e-7, 1e-4, 100, 0, ratio=10.0, node_ratio=0.01, between_ratio=10.0,
                        coordinate_ratio={"k": 10.0}, tolerance=1e-5)
    history = {"k": [("p", 1e4, 9, 9)]}  # 9 -> 17 nodes cut the error 1000-fold: log(1000) / 8 per node
    refined, _, _ = next_nodes(problem, check, {"k": 5.0}, history)  # the spectrum's rate is not used
    assert nodes(refined)["k"] == predicted(17, 10.0, math.log(1e3) / 8, TARGET)


def test_a_prediction_of_a_node_or_two_still_adds_a_quarter_of_the_intervals():
    problem = heat(x=33, t=33, g=9, k=9)
    check = pde_check(1.2, {"x": 1.2, "t": 1e-4, "g": 0.0, "k": 1e-4})
    refined, chosen, _ = next_nodes(problem, check, {"x": 5.0}, {})
    assert chosen == ["x"] and nodes(refined)["x"] == 33 + 8


@pytest.mark.parametrize("name, expected", [("x", 4 * 25 - 3), ("k", 2 * 25 - 1)])
def test_a_first_prediction_is_capped_and_a_parameter_past_65_nodes_doubles(name, expected):
    problem = heat(x=25, t=33, g=9, k=25)
    check = pde_check(1e6, {"x": 0.0, "t": 0.0, "g": 0.0, "k": 0.0, name: 1e6})
    refined, chosen, _ = next_nodes(problem, check, {name: 0.2}, {})
    assert chosen == [name] and predicted(25, 1e6, 0.2, TARGET) == 106
    # a space coordinate gets at most two doublings at once (a pre-asymptotic spectrum); a parameter that
    # may be split into elements is doubled and measured first (the gain decides between nodes and elements)
    assert nodes(refined)[name] == expected


def test_error_estimates_scale_the_tails_to_the_measured_error_and_keep_measured_shares():
    check = CheckResult(1e-4, 1e-4, 1e-4, 12, 0, ratio=10.0, node_ratio=10.0, between_ratio=10.0,
                        coordinate_ratio={"k": 3.0}, tail_ratio={"x": 2.0, "y": 3.0, "k": 100.0, "t": 0.0},
                        tolerance=1e-5)
    assert error_estimates(check, ["x", "y", "k", "t"]) == {"x": 4.0, "y": 6.0, "k": 3.0, "t": 10.0}
    small = CheckResult(1e-5, 1e-5, 1e-5, 12, 0, ratio=2.0, node_ratio=2.0, between_ratio=2.0,
                        tail_ratio={"x": 3.0}, tolerance=1e-5)
    assert error_estimates(small, ["x"]) == {"x": 3.0}  # a tail above the measured error is not scaled down


def random_points(cb, n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    return {c.name: rng.uniform(*c.domain, n) for c in cb.coordinates}


def rounds(cb) -> dict:
    """Per coordinate, its node counts over the rounds (the report's resolution_rounds)."""
    table = np.asarray(cb.report["resolution_rounds"])
    return {name: [int(v) for v in table[:, j]] for j, name in enumerate(cb.coordinate_names)}


def test_a_pde_refines_only_the_parameter_its_error_lacks_nodes_in():
    result = pgdcli.solve(parse_spec(HEAT, source="heat_k.yaml"))
    assert result.accurate is True, result.message
    cb = result.codebook
    tried = rounds(cb)
    assert len(tried["k"]) >= 2 and tried["k"][-1] > tried["k"][0]
    for name in ("x", "t", "g"):  # resolved at their first nodes, by their tails: never refined
        assert len(set(tried[name])) == 1, tried
    p = random_points(cb, 400, seed=3)
    exact = p["g"] * p["x"] + np.exp(-p["k"] * np.pi**2 * p["t"]) * np.sin(np.pi * p["x"])
    assert np.max(np.abs(cb.evaluate(p)["u"] - exact)) <= 1e-7


def test_an_ode_refines_only_the_parameter_its_error_lacks_nodes_in():
    result = pgdcli.solve(parse_spec(RELAXATION, source="relaxation_k.yaml"))
    assert result.accurate is True, result.message
    cb = result.codebook
    tried = rounds(cb)
    assert tried["k"][-1] > tried["k"][0] and len(set(tried["c"])) == 1 and len(set(tried["t"])) == 1, tried
    p = random_points(cb, 400, seed=4)
    exact = p["c"] / p["k"] + (1 - p["c"] / p["k"]) * np.exp(-p["k"] * p["t"])
    assert np.max(np.abs(cb.evaluate(p)["u"] - exact)) <= 1e-8
