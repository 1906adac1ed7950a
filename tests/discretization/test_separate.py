"""pgdcli.discretization.separate: numerical separation of node tensors, checked against the functions themselves."""

import numpy as np
import pytest

from pgdcli.problem.expressions import parse_expression
from pgdcli.discretization.coefficients import JointTrain, nodal_terms
from pgdcli.discretization.separate import DENSE_LIMIT, SeparationRankError, cp_from_tt, separate_function, tt_cross, tt_svd
from pgdcli.errors import SolverError


def _full(cores):
    out = cores[0][0]
    for c in cores[1:]:
        out = np.tensordot(out, c, axes=(-1, 0))
    return out[..., 0]


def _joint(text, coordinates=("t", "w", "a", "b", "k", "x")):
    poly = parse_expression(text, coordinates=coordinates, constants={}, unknowns=(), time="t", where="test")
    sep = poly.coefficient(())
    return sep


@pytest.mark.parametrize("delta", [1e-4, 1e-8, 1e-12])
def test_svd_of_two_coordinates_meets_the_bound_with_few_terms(delta):
    t = np.linspace(0, 10, 41)
    w = np.linspace(0.5, 2, 23)
    values = np.sin(np.outer(t, w))
    cores = tt_svd(values, delta)
    assert np.max(np.abs(_full(cores) - values)) <= delta
    # the bound is met with the fewest terms: one term fewer misses it (Eckart-Young)
    s = np.linalg.svd(values, compute_uv=False)
    r = cores[0].shape[2]
    assert np.sqrt(np.sum(s[r:] ** 2)) <= delta < np.sqrt(np.sum(s[r - 1:] ** 2))


def test_tt_svd_and_its_canonical_expansion_reproduce_a_three_way_function():
    a, b, c = np.linspace(0, 1, 17), np.linspace(0, 2, 19), np.linspace(-1, 1, 13)
    values = 1.0 / (1.0 + np.add.outer(np.multiply.outer(a, b), c ** 2))
    cores = tt_svd(values, 1e-9)
    terms = cp_from_tt(cores)
    assert len(terms) == int(np.prod([k.shape[2] for k in cores[:-1]]))
    rebuilt = sum(np.einsum("i,j,k->ijk", *term) for term in terms)
    assert np.max(np.abs(rebuilt - values)) <= 1e-9
    assert np.max(np.abs(_full(cores) - values)) <= 1e-9


def test_rank_cap_raises_with_the_rank_reached():
    rng = np.random.default_rng(0)
    with pytest.raises(SeparationRankError) as info:
        tt_svd(rng.standard_normal((30, 30)), 1e-6, max_rank=5)
    assert info.value.rank == 5 and info.value.error > 1e-6


@pytest.mark.parametrize("function", [
    lambda x: 1.0 / (1.0 + x.sum(axis=1)),
    lambda x: np.exp(-3 * x[:, 0] * x[:, 1]) * np.sin(4 * x[:, 2] + x[:, 3] * x[:, 4]),
])
def test_cross_approximation_of_a_five_way_function_at_random_entries(function):
    x = np.linspace(0, 1, 24)
    shape = (24,) * 5

    def at(index):
        return function(x[index])

    sep = tt_cross(at, shape, 1e-8)
    assert sep.method == "tt-cross"
    index = np.random.default_rng(11).integers(0, 24, (4000, 5))  # not the cross's own check entries
    values = np.einsum("na,na->n", _rows(sep.cores, index[:, :-1]), sep.cores[-1][:, index[:, -1], 0].T)
    assert np.max(np.abs(values - at(index))) <= 1e-7


def _rows(cores, index):
    out = cores[0][0][index[:, 0]]
    for k in range(1, index.shape[1]):
        out = np.einsum("na,anb->nb", out, cores[k][:, index[:, k], :])
    return out


def test_separate_function_uses_the_cross_beyond_the_dense_limit(monkeypatch):
    import pgdcli.discretization.separate as separate

    monkeypatch.setattr(separate, "DENSE_LIMIT", 1000)
    nodes = {"a": np.linspace(0, 1, 15), "b": np.linspace(0, 1, 16), "c": np.linspace(0, 1, 17)}
    sep = separate_function(lambda v: np.exp(-v["a"] * v["b"] - v["c"]), nodes, 1e-9)
    assert sep.method == "tt-cross"
    grid = np.meshgrid(*nodes.values(), indexing="ij")
    assert np.max(np.abs(_full(sep.cores) - np.exp(-grid[0] * grid[1] - grid[2]))) <= 1e-8
    assert DENSE_LIMIT > 1000


def test_nodal_terms_sum_to_the_coefficient_at_every_node():
    sep = _joint("2*k*sin(w*t) + exp(-a*t)/(1 + a*b) + 3*k")
    nodes = {"t": np.linspace(0, 5, 12), "w": np.linspace(0.5, 2, 7), "a": np.linspace(0, 1, 6),
             "b": np.linspace(0, 2, 5), "k": np.linspace(1, 3, 4), "x": np.linspace(0, 1, 3)}
    reports = []
    terms = nodal_terms(sep, nodes, 1e-10, reports=reports)
    grid = np.meshgrid(*nodes.values(), indexing="ij")
    values = dict(zip(nodes, grid))
    total = sum(coef * np.einsum("t,w,a,b,k,x->twabkx", *(v[c] for c in nodes)) for coef, v in terms)
    exact = 2 * values["k"] * np.sin(values["w"] * values["t"]) + np.exp(-values["a"] * values["t"]) / (
        1 + values["a"] * values["b"]) + 3 * values["k"]
    assert np.max(np.abs(total - exact)) <= 3e-10
    assert sorted(sorted(r["coordinates"]) for r in reports) == [["a", "b", "t"], ["t", "w"]]
    assert all(r["terms"] >= 2 for r in reports)


def test_a_coefficient_that_is_not_finite_at_a_node_is_named():
    sep = _joint("1/(a - b)")
    nodes = {"a": np.linspace(0, 1, 5), "b": np.linspace(0, 1, 5)}
    with pytest.raises(SolverError, match=r"the coefficient '1/\(a - b\)' is not finite at some nodes of a, b"):
        nodal_terms(sep, nodes, 1e-8)


def test_joint_train_embeds_parameters_and_follows_time():
    sep = _joint("exp(-a*t)*sin(b*t) + 1/(1 + a*k)")
    params = ["a", "w", "b", "k"]
    nodes = {"a": np.linspace(0, 1, 6), "w": np.linspace(0, 1, 3), "b": np.linspace(0, 2, 7),
             "k": np.linspace(1, 2, 4)}
    grid = dict(zip(params, np.meshgrid(*(nodes[p] for p in params), indexing="ij")))
    timed, fixed = sep.joints
    for t in (0.0, 0.7, 2.5):
        train = JointTrain(timed, "t", params, nodes, 1e-11)
        exact = np.exp(-grid["a"] * t) * np.sin(grid["b"] * t)
        assert np.max(np.abs(_full(train.at(t)) - exact)) <= 1e-11
    train = JointTrain(fixed, "t", params, nodes, 1e-11)
    assert np.max(np.abs(_full(train.at(3.0)) - 1 / (1 + grid["a"] * grid["k"]))) <= 1e-11


def test_the_order_with_the_fewest_canonical_terms_is_kept():
    sep = _joint("exp(-a*t)*sin(w*t)")
    nodes = {"t": np.linspace(0, 8, 33), "a": np.linspace(0.1, 1, 17), "w": np.linspace(0.5, 2, 17)}
    reports = []
    nodal_terms(sep, nodes, 1e-9, reports=reports)
    (report,) = reports
    ordered = tt_svd(np.exp(-np.multiply.outer(nodes["t"], nodes["a"]))[:, :, None]
                     * np.sin(np.multiply.outer(nodes["t"], nodes["w"]))[:, None, :], 1e-9)
    spec_order_terms = int(np.prod([c.shape[2] for c in ordered[:-1]]))
    assert report["coordinates"][1] == "t" and report["terms"] < spec_order_terms


def test_an_order_past_the_rank_cap_does_not_stop_the_search_for_one_within_it():
    # a Gaussian at (a, b): ordered (x, y, a, b) its ranks are the square of those ordered (x, a, y, b)
    sep = _joint("exp(-((x - a)**2 + (y - b)**2)/0.01)", coordinates=("t", "x", "y", "a", "b"))
    nodes = {"x": np.linspace(0, 1, 33), "y": np.linspace(0, 1, 33), "a": np.linspace(0.3, 0.7, 17),
             "b": np.linspace(0.3, 0.7, 17)}
    with pytest.raises(SeparationRankError):
        separate_function(lambda v: np.exp(-((v["x"] - v["a"]) ** 2 + (v["y"] - v["b"]) ** 2) / 0.01), nodes,
                          1e-9, max_rank=40)
    reports = []
    terms = nodal_terms(sep, nodes, 1e-7, reports=reports, max_rank=40)
    (report,) = reports
    assert report["ranks"][1] == 1 and max(report["ranks"]) <= 40
    grid = dict(zip(nodes, np.meshgrid(*nodes.values(), indexing="ij")))
    total = sum(coef * np.einsum("x,y,a,b->xyab", *(v[c] for c in nodes)) for coef, v in terms)
    exact = np.exp(-((grid["x"] - grid["a"]) ** 2 + (grid["y"] - grid["b"]) ** 2) / 0.01)
    assert np.max(np.abs(total - exact)) <= 1e-7
