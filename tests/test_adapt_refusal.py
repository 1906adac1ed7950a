"""The refusal's advice for a coordinate at solver.max_nodes (pgdcli.adapt.refusal): the cap predicted from the
measured fall of its error, worked out here from the two models the prediction assumes (geometric under
p-refinement, ``r * exp(-rate (m - n))``; algebraic once elements are split, ``r * (m / n)**-order``, in node
intervals), and no suggestion where the error was not falling or one slow refinement cannot tell its rate.
"""

from __future__ import annotations

import dataclasses
import math

from conftest import spec_text
from pgdcli import parse_spec
from pgdcli.adapt.refusal import cap_advice, predicted_cap
from pgdcli.adapt.resolution import REFINE_AT


def capped(max_nodes: int, p_nodes: int):
    """A problem whose automatic coordinate p has ``p_nodes`` nodes under ``solver.max_nodes``."""
    text = spec_text(coordinates={"t": "{domain: [0, 1]}", "p": "{domain: [0, 1]}"},
                     unknowns={"u": "{initial: p}"}, equations=['"der(u) = -u"'],
                     solver=f" {{max_nodes: {max_nodes}}}")
    problem = parse_spec(text, source="capped.yaml")
    coords = tuple(dataclasses.replace(c, nodes=p_nodes) if c.name == "p" else c for c in problem.coordinates)
    return dataclasses.replace(problem, coordinates=coords)


def test_a_geometric_fall_under_more_nodes_predicts_by_its_rate_per_node():
    # 9 -> 17 nodes cut the error 1000-fold: log(1000) / 8 per node; 10 x the tolerance falls to REFINE_AT
    need, words = predicted_cap(17, 10.0, [("p", 1e4, 9, 9)], None)
    assert need == math.ceil(17 + math.log(10.0 / REFINE_AT) / (math.log(1e3) / 8))
    assert words == "its error fell 1e+03x per doubling of its nodes"


def test_an_algebraic_fall_under_elements_predicts_by_its_order():
    # 16 -> 32 node intervals cut the error 4-fold: order 2
    need, _ = predicted_cap(33, 10.0, [("p", 100.0, 9, 9), ("h", 40.0, 17, 17)], None)
    assert need == math.ceil(32 * (10.0 / REFINE_AT) ** 0.5) + 1
    assert cap_advice(capped(33, 33), "p", 10.0, [("p", 100.0, 9, 9), ("h", 40.0, 17, 17)], None).endswith(
        "its error fell 4x per doubling of its nodes: solver.max_nodes: 257 is predicted to meet it")


def test_an_error_that_did_not_fall_gets_no_larger_cap():
    past = [("p", 100.0, 9, 9), ("h", 10.0, 17, 17)]
    assert predicted_cap(33, 9.0, past, None)[0] == 0
    advice = cap_advice(capped(33, 33), "p", 9.0, past, None)
    assert "not predicted to meet it" in advice and "solver.max_nodes:" not in advice


def test_one_slow_refinement_is_too_few_to_extrapolate():
    # a sharp feature falls slowly until its scale is resolved: one 2.5-fold step predicts nothing
    assert predicted_cap(17, 40.0, [("p", 100.0, 9, 9)], None)[0] == -1
    advice = cap_advice(capped(17, 17), "p", 40.0, [("p", 100.0, 9, 9)], None)
    assert "over one refinement: too few refinements to predict" in advice and "solver.max_nodes:" not in advice


def test_a_grading_leaves_no_rate_to_predict_by():
    # a graded mesh starts again at fewer nodes per element: fewer nodes in all need not mean a rising error
    past = [("p", 1e3, 9, 9, -1), ("g", 500.0, 17, 17, -1)]
    assert predicted_cap(41, 90.0, past, None)[0] == -1
    advice = cap_advice(capped(41, 41), "p", 90.0, past, None)
    assert "graded at its last refinement" in advice and "solver.max_nodes:" not in advice


def test_without_a_refinement_the_spectrum_gives_the_rate():
    need, words = predicted_cap(9, 1e4, [], math.log(2.0))
    assert need == math.ceil(9 + math.log(1e4 / REFINE_AT) / math.log(2.0)) and "2x per node" in words
    assert predicted_cap(9, 1e4, [], None) is None
    assert cap_advice(capped(9, 9), "p", 1e4, [], math.log(2.0)).endswith("solver.max_nodes: 33 is predicted to meet it")


def test_a_cap_past_the_largest_allowed_is_not_suggested():
    advice = cap_advice(capped(33, 33), "p", 1e5, [("p", 1e6, 9, 9), ("h", 2e5, 17, 17)], None)  # order 1
    assert "no solver.max_nodes up to 2000" in advice and "solver.max_nodes:" not in advice
