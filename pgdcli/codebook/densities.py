"""Input densities of a sensitivity analysis and their quadrature on a coordinate's basis.

A coordinate's codebook functions are polynomials on each piece of its basis (a Chebyshev slab or
element, a linear element), of degree ``m - 1`` for ``m`` nodes a piece. Gauss-Legendre with ``m``
points a piece therefore integrates a product of two of them exactly against a density that is
constant on each piece (:class:`Uniform`, also over a sub-interval): the means, variances and Sobol
indices of :mod:`pgdcli.codebook.sensitivity` are then those of the codebook's own function, to
rounding. A smooth density that is not piecewise constant (:class:`TruncatedNormal`, or any callable)
is integrated on pieces no wider than a fraction of its length scale with extra points, which
brings the quadrature error to rounding for the densities one meets (tested against closed forms).

numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np

from ..errors import QueryError

__all__ = ["Density", "Uniform", "TruncatedNormal", "Custom", "parse_density", "quadrature"]

EXTRA_POINTS = 16      # Gauss points beyond the basis's own on each piece of a smooth density
PIECES_PER_SCALE = 4   # pieces per length scale of a smooth density (a normal's standard deviation)
MAX_PIECES = 4096      # a coordinate's quadrature pieces (a tiny standard deviation is refused beyond)


class Density:
    """A probability density of one coordinate (normalized by the quadrature, not by the caller)."""

    #: a length scale below which the density varies (None: constant on its support)
    scale: float | None = None

    def support(self, low: float, high: float) -> tuple[float, float]:
        """Where the density is positive, within ``[low, high]``."""
        return low, high

    def pdf(self, x: np.ndarray) -> np.ndarray:
        """The (unnormalized) density at ``x`` inside :meth:`support`."""
        return np.ones_like(x)

    def describe(self) -> str:
        raise NotImplementedError


@dataclass(frozen=True)
class Uniform(Density):
    """Uniform over ``[low, high]`` (None: the coordinate's whole domain)."""

    low: float | None = None
    high: float | None = None

    def support(self, low, high):
        lo = low if self.low is None else self.low
        hi = high if self.high is None else self.high
        return lo, hi

    def describe(self) -> str:
        if self.low is None and self.high is None:
            return "uniform"
        return f"uniform:{self.low!r},{self.high!r}"


@dataclass(frozen=True)
class TruncatedNormal(Density):
    """A normal density of ``mean`` and standard deviation ``sd``, truncated to the domain."""

    mean: float
    sd: float

    @property
    def scale(self) -> float:
        return self.sd

    def pdf(self, x):
        return np.exp(-0.5 * ((x - self.mean) / self.sd) ** 2)

    def describe(self) -> str:
        return f"normal:{self.mean!r},{self.sd!r}"


@dataclass(frozen=True)
class Custom(Density):
    """A density given as a Python callable ``pdf(x)`` (vectorized, nonnegative); ``scale`` its length scale."""

    function: Callable
    scale: float | None = None
    name: str = "custom"

    def pdf(self, x):
        return np.asarray(self.function(x), dtype=float) * np.ones_like(x)

    def describe(self) -> str:
        return self.name


def parse_density(text: str, name: str | None = None) -> Density:
    """``uniform``, ``uniform:LOW,HIGH`` or ``normal:MEAN,SD`` -> a :class:`Density` (not yet checked
    against a domain: :func:`quadrature` does that); errors name ``--density NAME=TEXT``."""
    option = f"--density {name}=" if name is not None else "--density "
    kind, _, args = str(text).strip().partition(":")
    kind = kind.strip().lower()
    try:
        values = [float(a) for a in args.split(",")] if args.strip() else []
    except ValueError:
        raise QueryError(f"{option}{text}: the parameters must be numbers (e.g. normal:2.0,0.3)") from None
    if any(not math.isfinite(v) for v in values):
        raise QueryError(f"{option}{text}: the parameters must be finite numbers")
    if kind == "uniform" and len(values) in (0, 2):
        if values and not values[0] < values[1]:
            raise QueryError(f"{option}{text}: uniform:LOW,HIGH needs LOW < HIGH")
        return Uniform(*values) if values else Uniform()
    if kind == "normal" and len(values) == 2:
        if not values[1] > 0:
            raise QueryError(f"{option}{text}: the standard deviation of normal:MEAN,SD must be positive")
        return TruncatedNormal(values[0], values[1])
    raise QueryError(f"{option}{text}: expected uniform, uniform:LOW,HIGH or normal:MEAN,SD")


@lru_cache(maxsize=64)
def _gauss_legendre(points: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre points and weights on [-1, 1] (numpy finds them by an eigenvalue problem: kept)."""
    return np.polynomial.legendre.leggauss(points)


def _pieces(basis) -> np.ndarray:
    """The boundaries of the pieces on which the basis's functions are polynomials, and their nodes a piece."""
    if basis.kind == "linear":
        return np.asarray(basis.nodes, dtype=float), 2
    breakpoints = getattr(basis, "breakpoints", ())
    if len(breakpoints) > 2:
        return np.asarray(breakpoints, dtype=float), int(basis.slab_size)
    return np.array([basis.domain[0], basis.domain[1]], dtype=float), int(basis.nodes.size)


def quadrature(name: str, basis, density: Density | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points and weights (summing to 1) of the density of coordinate ``name`` on its basis.

    Parameters
    ----------
    name : str
        The coordinate (error messages).
    basis : Basis1D
        Its basis (pieces, nodes a piece).
    density : Density, optional
        Default: uniform over the domain.

    Returns
    -------
    x, w : ndarray, shape (Q,)
        ``w @ f(x)`` is the density's mean of ``f``; exact for the product of two of the basis's
        functions under a piecewise-constant density.

    Raises
    ------
    QueryError
        A support outside the domain, or a density without mass on it.
    """
    density = Uniform() if density is None else density
    low, high = float(basis.domain[0]), float(basis.domain[1])
    lo, hi = (float(v) for v in density.support(low, high))
    if not (low <= lo < hi <= high):
        raise QueryError(f"--density {name}={density.describe()}: [{lo:g}, {hi:g}] is not an interval inside the "
                         f"domain [{low:g}, {high:g}] of {name!r}")
    bounds, per_piece = _pieces(basis)
    inner = bounds[(bounds > lo) & (bounds < hi)]
    cuts = np.concatenate([[lo], inner, [hi]])
    points = per_piece + (EXTRA_POINTS if density.scale is not None else 0)
    if density.scale is not None:
        scale = float(density.scale)
        split = np.maximum(1, np.ceil(np.diff(cuts) * PIECES_PER_SCALE / scale)).astype(int)
        if split.sum() > MAX_PIECES:
            raise QueryError(f"--density {name}={density.describe()}: its length scale {scale:g} is too small for "
                             f"the domain [{low:g}, {high:g}] (over {MAX_PIECES} quadrature pieces)")
        cuts = np.concatenate([np.linspace(a, b, k + 1)[:-1] for a, b, k in zip(cuts[:-1], cuts[1:], split)] + [[hi]])
    unit_x, unit_w = _gauss_legendre(points)
    a, b = cuts[:-1, None], cuts[1:, None]
    x = (a + (b - a) * (unit_x + 1.0) / 2.0).reshape(-1)
    w = ((b - a) / 2.0 * unit_w).reshape(-1) * density.pdf(x)
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise QueryError(f"--density {name}={density.describe()}: the density is negative or not finite on the domain")
    total = w.sum()
    if not total > 0:
        raise QueryError(f"--density {name}={density.describe()}: no probability inside the domain "
                         f"[{low:g}, {high:g}] of {name!r}")
    return x, w / total
