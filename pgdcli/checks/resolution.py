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

Computed from the separated form, never from the full tensor. numpy only.
"""

from __future__ import annotations

import numpy as np

from ..tensors.cp import orthogonal_sweep
from ..tensors.tt import tt_centre_cores

__all__ = ["resolution_tails"]


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


def resolution_tails(codebook) -> dict[str, dict[str, float]]:
    """Tail indicator per unknown and coordinate (NaN when the coordinate is too coarse to tell).

    Returns
    -------
    dict
        ``{unknown: {coordinate: rms tail}}``.
    """
    from ..codebook.codebook import FieldTT

    coords = codebook.coordinates
    sizes = [c.nodes for c in coords]
    total = float(np.prod(sizes))
    tails = [_tail_matrix(c) for c in coords]
    out: dict[str, dict[str, float]] = {}
    for name, fm in codebook.fields.items():
        res = {}
        if isinstance(fm, FieldTT):
            centres = tt_centre_cores(fm.cores)
            for core, j in zip(centres, fm.mode_order):
                t = tails[j]
                if t is None:
                    res[coords[j].name] = float("nan")
                    continue
                coef = np.einsum("kn,anb->akb", t, core)
                per = np.sqrt(np.sum(coef * coef, axis=(0, 2)))  # Frobenius over the other coordinates
                res[coords[j].name] = float(per.max() / np.sqrt(total / sizes[j]))
        else:
            a = fm.alphas
            for j, c in enumerate(coords):
                t = tails[j]
                if t is None or a.size == 0:
                    res[c.name] = float("nan") if t is None else 0.0
                    continue
                # norms over the other coordinates through an orthogonal sweep, not Gram products:
                # a tail far below the terms (a lift cancelled by the modes) would drown in the
                # sqrt(eps) cancellation error of w @ G @ w
                others = [m for k, m in enumerate(fm.modes) if k != j]
                z = orthogonal_sweep(others) if others else np.ones((1, a.size))
                coef = z @ (a[:, None] * (t @ fm.modes[j]).T)  # (r, tail rows)
                worst = float(np.linalg.norm(coef, axis=0).max())
                res[c.name] = worst / np.sqrt(total / sizes[j])
        out[name] = res
    return out
