"""The Chebyshev-tail resolution check, from the separated form, against the full nodal tensor."""

from __future__ import annotations

import numpy as np

from pgdcli.codebook.codebook import Codebook, CoordinateInfo, CPTensor
from pgdcli.checks.resolution import resolution_tails

COORDS = (CoordinateInfo("x", (0.0, 1.0), 9, "chebyshev", "space"),
          CoordinateInfo("k", (1.0, 3.0), 7, "chebyshev", "parameter"),
          CoordinateInfo("c", (-1.0, 1.0), 3, "linear", "parameter"))


def _nodes(info):
    return info.basis().nodes


def _full_tail(full: np.ndarray, axis: int, info) -> float:
    """max over the last two Chebyshev coefficients along ``axis`` of their RMS over the other axes,
    with the coefficients from numpy's own interpolating fit."""
    x = _nodes(info)
    moved = np.moveaxis(full, axis, 0).reshape(x.size, -1)
    t = 2.0 * (x - info.domain[0]) / (info.domain[1] - info.domain[0]) - 1.0
    coef = np.polynomial.chebyshev.chebfit(t, moved, x.size - 1)  # (n, others)
    return float(max(np.sqrt(np.mean(coef[-2] ** 2)), np.sqrt(np.mean(coef[-1] ** 2))))


def _full(field: CPTensor) -> np.ndarray:
    return np.einsum("r,ir,jr,kr->ijk", field.weights, *field.factors)


def test_tails_of_a_cp_codebook_match_the_full_tensor():
    x, k, c = (_nodes(i) for i in COORDS)
    modes = (np.column_stack([np.exp(x), np.sin(3 * x)]), np.column_stack([1 / k, k**2]),
             np.column_stack([np.ones_like(c), c]))
    field = CPTensor(np.array([1.0, 0.5]), modes)
    tails = resolution_tails(Codebook(COORDS, {"u": field}))["u"]
    full = _full(field)
    for axis in (0, 1):
        expected = _full_tail(full, axis, COORDS[axis])
        assert expected > 1e-8
        assert abs(tails[COORDS[axis].name] - expected) <= 1e-10 * expected
    # linear coordinate: second differences over 8 (c enters linearly: none)
    assert tails["c"] <= 1e-15


def test_a_small_tail_under_large_cancelling_terms_is_resolved():
    # a lift-like term with a large tail (a cardinal function) cancelled by the next term, plus a
    # smooth term: the tail is the smooth term's, far below sqrt(eps) times the large terms
    x, k, c = (_nodes(i) for i in COORDS)
    spike = np.zeros_like(x)
    spike[-1] = 1.0
    smooth = np.exp(0.2 * x)
    # spike (k - (k - 1) - 1) = 0: the cancellation is between different vectors, as between a
    # lift and the modes; Gram products w G w lose it (measured: -6e-11, i.e. 0, for a true 3e-13)
    modes = (np.column_stack([spike, spike, spike, smooth]),
             np.column_stack([k, k - 1, np.ones_like(k), np.ones_like(k)]), np.column_stack([np.ones_like(c)] * 4))
    field = CPTensor(np.array([1e3, -1e3, -1e3, 1.0]), modes)
    tails = resolution_tails(Codebook(COORDS, {"u": field}))["u"]
    expected = _full_tail(_full(field), 0, COORDS[0])
    assert 0 < expected < 1e-12
    assert expected / 10 <= tails["x"] <= 10 * expected


def test_chebyshev_decay_is_the_bernstein_ellipse_of_a_pole():
    """1/(1 + (x - 0.3)^2) on [-1, 1] has poles at 0.3 +- i: its coefficients fall like rho**-k with
    rho = |z + sqrt(z^2 - 1)| at the pole (the Bernstein ellipse through it), which the fitted
    decay must recover; the linear coordinate and the one with too few nodes are left out."""
    from pgdcli.checks.resolution import chebyshev_decay

    info = (CoordinateInfo("x", (-1.0, 1.0), 33, "chebyshev", "parameter"),
            CoordinateInfo("k", (1.0, 3.0), 7, "chebyshev", "parameter"),
            CoordinateInfo("c", (-1.0, 1.0), 3, "linear", "parameter"))
    x, k, c = (_nodes(i) for i in info)
    field = CPTensor(np.array([1.0]), (np.column_stack([1 / (1 + (x - 0.3) ** 2)]),
                                         np.column_stack([k]), np.column_stack([1 + c])))
    decay = chebyshev_decay(Codebook(info, {"u": field}))
    z = 0.3 + 1j
    rho = max(abs(z + np.sqrt(z * z - 1)), abs(z - np.sqrt(z * z - 1)))
    assert set(decay) == {"x"}
    assert abs(decay["x"] - np.log(rho)) < 0.05 * np.log(rho)


def test_chebyshev_decay_skips_a_resolved_coordinate():
    """A polynomial of low degree is resolved: its spectrum is at rounding level, nothing to extrapolate."""
    from pgdcli.checks.resolution import chebyshev_decay

    info = (CoordinateInfo("x", (-1.0, 1.0), 17, "chebyshev", "parameter"),)
    x = _nodes(info[0])
    field = CPTensor(np.array([1.0]), (np.column_stack([1 + x + x**3]),))
    assert chebyshev_decay(Codebook(info, {"u": field})) == {}
