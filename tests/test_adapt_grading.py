"""Graded elements (pgdcli.adapt.grading): where the worst off-node error lies, and the geometric mesh toward it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import spec_text
from pgdcli import parse_spec
from pgdcli.adapt.grading import GRADED_NODES, GRADING, MAX_LAYERS, error_end, graded_elements


def problem_with(breakpoints=(), nodes: int = 17):
    text = spec_text(coordinates={"t": "{domain: [0, 1]}", "p": "{domain: [0, 2]}"}, unknowns={"u": "{initial: p}"},
                     equations=['"der(u) = -u"'])
    problem = parse_spec(text, source="graded.yaml")
    coords = tuple(dataclasses.replace(c, breakpoints=breakpoints, nodes=nodes) if c.name == "p" else c
                   for c in problem.coordinates)
    return dataclasses.replace(problem, coordinates=coords)


@pytest.mark.parametrize("worst, breakpoints, end", [
    (0.1, (), -1), (0.45, (), -1), (1.9, (), 1), (1.0, (), 0), (0.6, (), 0),
    (0.2, (0.0, 1.0, 2.0), -1), (0.3, (0.0, 1.0, 2.0), 0), (1.8, (0.0, 1.0, 2.0), 1), (0.9, (0.0, 1.0, 2.0), 0)])
def test_the_error_counts_at_an_end_only_near_it_in_the_end_element(worst, breakpoints, end):
    c = problem_with(breakpoints).coordinate("p")
    x = np.array([0.05, 0.7, 1.3, worst])
    r = np.array([1.0, 2.0, 3.0, 10.0])
    assert error_end(c, x, r) == end


def test_an_end_element_is_graded_geometrically_toward_the_end():
    problem = problem_with((0.0, 1.0, 2.0), nodes=33)
    x, r = np.array([0.5, 0.0123, 1.5]), np.array([1.0, 50.0, 2.0])  # the worst 0.0123 from the low end
    c = graded_elements(problem, "p", -1, x, r).coordinate("p")
    # layers to one GRADING step below 0.0123: 0.2, 0.04, 0.008, 0.0016
    layers = int(np.ceil(np.log(0.0123) / np.log(GRADING))) + 1
    assert np.allclose(c.breakpoints, [0.0, *sorted(GRADING ** np.arange(1, layers + 1)), 1.0, 2.0])
    assert c.nodes == GRADED_NODES
    high = graded_elements(problem, "p", 1, np.array([1.999]), np.array([5.0])).coordinate("p")
    assert np.allclose(high.breakpoints, [0.0, 1.0, *(2.0 - GRADING ** np.arange(1, MAX_LAYERS + 1)), 2.0])
    assert graded_elements(problem_with(nodes=5), "p", 1, np.array([1.0]), np.array([5.0])).coordinate("p").nodes == 5
