"""A posteriori resolution check of a codebook: Chebyshev tails per coordinate.

A solver's residual or step error says how well the *discrete* problem was
solved; between the nodes the codebook interpolates, and that error is only
small if every coordinate has enough nodes. For a Chebyshev coordinate the
size of the last Chebyshev coefficients of the solution along it estimates
the interpolation error (they decay geometrically for smooth solutions), so
this module reports, per unknown and coordinate, the root-mean-square over
the other coordinates' nodes of ``max(|c_{n-2}|, |c_{n-1}|)``. Linear
coordinates get the largest second difference over 8 instead (the
piecewise-linear interpolation error of a smooth function).

Computed from the separated form, never from the full tensor. The decay of the
Chebyshev coefficients (:func:`chebyshev_decay`) gives the nodes a coordinate needs
(:func:`nodes_for_decay`); :func:`error_estimates` shares a measured error among the
coordinates. numpy only.
"""

from __future__ import annotations

import numpy as np

from ..tensors.cp_sweep import orthogonal_sweep
from ..tensors.tt import TT, tt_centre_cores

__all__ = ["resolution_tails", "chebyshev_spectra", "chebyshev_decay", "spectrum_decay", "error_estimates",
           "nodes_for_decay", "MIN_GROWTH"]

#: Fewest new node intervals of a refinement, as a fraction of a coordinate's: a prediction a little short
#: costs a whole solve, a few nodes more only a part of one.
MIN_GROWTH = 0.25


def _coefficient_matrix(n: int) -> np.ndarray:
    """Values at the n Chebyshev-Lobatto points (increasing) -> Chebyshev coefficients."""
    x = np.sin(np.pi * (2.0 * np.arange(n) - (n - 1)) / (2.0 * (n - 1)))
    return np.linalg.inv(np.polynomial.chebyshev.chebvander(x, n - 1))


def _tail_matrix(info) -> np.ndarray | None:
    """Rows that map nodal values along a coordinate to its tail indicators."""
    n = info.nodes
    if getattr(info, "breakpoints", ()):
        return None  # piecewise: each slab is the march's own step polynomial, no global tail
    if info.discretization == "chebyshev":
        if n < 4:
            return None
        return _coefficient_matrix(n)[-2:]
    if n < 3:
        return None
    second = np.zeros((n - 2, n))
    for i in range(n - 2):
        second[i, i:i + 3] = (1.0, -2.0, 1.0)
    return second / 8.0


def _row_norms(codebook, matrices) -> dict[str, dict[str, np.ndarray | None]]:
    """RMS over the other coordinates' nodes of each row of ``matrices[j] @ (values along coordinate j)``.

    Parameters
    ----------
    codebook : pgdcli.codebook.Codebook
    matrices : list of (m_j, n_j) ndarray or None
        Per coordinate, in codebook order (None: not computed).

    Returns
    -------
    dict
        ``{unknown: {coordinate: (m_j,) ndarray or None}}``.
    """
    coords = codebook.coordinates
    sizes = [c.nodes for c in coords]
    total = float(np.prod(sizes))
    out: dict[str, dict] = {}
    for name, fm in codebook.fields.items():
        res: dict = {c.name: None for c in coords}
        if isinstance(fm, TT):
            centres = tt_centre_cores(fm.cores)
            for core, j in zip(centres, fm.mode_order):
                if matrices[j] is not None:
                    coef = np.einsum("kn,anb->akb", matrices[j], core)
                    res[coords[j].name] = np.sqrt(np.sum(coef * coef, axis=(0, 2)) / (total / sizes[j]))
        else:
            a = fm.weights
            for j, c in enumerate(coords):
                if matrices[j] is None:
                    continue
                if a.size == 0:
                    res[c.name] = np.zeros(matrices[j].shape[0])
                    continue
                # norms over the other coordinates through an orthogonal sweep, not Gram products:
                # a tail far below the terms (a lift cancelled by the modes) would drown in the
                # sqrt(eps) cancellation error of w @ G @ w
                others = [m for k, m in enumerate(fm.factors) if k != j]
                z = orthogonal_sweep(others) if others else np.ones((1, a.size))
                coef = z @ (a[:, None] * (matrices[j] @ fm.factors[j]).T)  # (r, rows)
                res[c.name] = np.linalg.norm(coef, axis=0) / np.sqrt(total / sizes[j])
        out[name] = res
    return out


def resolution_tails(codebook) -> dict[str, dict[str, float]]:
    """Tail indicator per unknown and coordinate (NaN when the coordinate is too coarse to tell).

    Returns
    -------
    dict
        ``{unknown: {coordinate: rms tail}}``.
    """
    norms = _row_norms(codebook, [_tail_matrix(c) for c in codebook.coordinates])
    return {u: {c: float("nan") if v is None else float(v.max()) for c, v in per.items()}
            for u, per in norms.items()}


def chebyshev_spectra(codebook, min_nodes: int = 2) -> dict[str, np.ndarray]:
    """The Chebyshev coefficients of a codebook along each Chebyshev coordinate of one piece with at least
    ``min_nodes`` nodes: per degree, the RMS over the other coordinates' nodes, the largest over the unknowns.

    Returns
    -------
    dict of str to ndarray (n,)
        Per coordinate, degree 0 first, ``n`` its nodes.
    """
    matrices = [_coefficient_matrix(c.nodes) if c.discretization == "chebyshev" and c.nodes >= min_nodes
                and not getattr(c, "breakpoints", ()) else None for c in codebook.coordinates]
    norms = _row_norms(codebook, matrices)
    return {c.name: np.max([per[c.name] for per in norms.values()], axis=0)
            for c, m in zip(codebook.coordinates, matrices) if m is not None}


def chebyshev_decay(codebook) -> dict[str, float]:
    """Per Chebyshev coordinate of one piece, the geometric decay of its Chebyshev coefficients per node.

    The coefficients ``|c_k|`` of an analytic function fall like ``rho**-k``; the
    slope of ``log |c_k|`` over the upper half of the spectrum (:func:`chebyshev_spectra`),
    fitted by least squares, is ``log rho``: with it, the nodes that bring an interpolation
    error down by a factor follow from one solve (chebfun reads the same plateau-free part of
    the series in ``standardChop``). Coordinates with fewer than 8 nodes, with
    elements, linear ones, and spectra already at rounding level are left out.

    Returns
    -------
    dict
        ``{coordinate: log rho}`` (positive: decaying).
    """
    decays = {name: spectrum_decay(spectrum) for name, spectrum in chebyshev_spectra(codebook, min_nodes=8).items()}
    return {name: rate for name, rate in decays.items() if rate is not None}


def spectrum_decay(spectrum: np.ndarray) -> float | None:
    """``log rho`` of a Chebyshev spectrum (degree 0 first): the least-squares slope of the log of its envelope
    from the right over its upper half (see :func:`chebyshev_decay`); None at rounding level."""
    nodes = spectrum.size
    # the envelope from the right: an even or odd function has every other coefficient zero
    envelope = np.maximum.accumulate(spectrum[::-1])[::-1]
    upper = np.arange(nodes // 2, nodes)
    s = envelope[upper]
    if not np.all(s > 1e-13 * max(spectrum.max(), 1e-300)):
        return None  # at rounding level: the coordinate is resolved, nothing to extrapolate
    return float(-np.polyfit(upper, np.log(s), 1)[0])


def nodes_for_decay(nodes: int, factor: float, per_node: float) -> int:
    """Nodes that cut an error falling by ``exp(per_node)`` per node ``factor``-fold, and at least
    :data:`MIN_GROWTH` more intervals than ``nodes`` (a prediction a little short costs a whole solve)."""
    predicted = int(np.ceil(nodes + np.log(factor) / per_node))
    return max(predicted, nodes + int(np.ceil(MIN_GROWTH * (nodes - 1))))


def error_estimates(check, names) -> dict[str, float]:
    """Per named coordinate, its share of the measured error, as a ratio to the tolerance.

    Where the check samples a coordinate off its nodes (a parameter or time of an
    ODE), the share is that measured ratio. Elsewhere (the space and time of a
    PDE, whose check measures the error as a whole) the Chebyshev tails estimate
    it, scaled up together when they add up to less than the measured error they
    must explain (a tail is the size of the last coefficients, not of the error
    between the nodes); a coordinate without a tail (too few nodes, linear
    elements) is given the whole measured error.
    """
    measured = {n: check.coordinate_ratio[n] for n in names if n in check.coordinate_ratio}
    tails = {n: check.tail_ratio.get(n, 0.0) for n in names if n not in measured}
    total = sum(tails.values())
    whole = check.ratio if np.isfinite(check.ratio) else 0.0
    scale = max(1.0, whole / total) if total > 0 else 1.0
    return {**measured, **{n: tail * scale if tail > 0 else whole for n, tail in tails.items()}}
