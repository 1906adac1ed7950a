"""A codebook's unknowns: a separated sum (:class:`~pgdcli.tensors.cp.CPTensor`) or a tensor train
(:class:`~pgdcli.tensors.tt.TT`) of nodal values, checked against the codebook's coordinates.

The tensor types check their own structure (a factor's columns, a core's ranks, the mode order)
with ValueErrors that name the factor or core; here a field is checked against the coordinates
(nodes per mode, finite values), with a CodebookError that names the unknown and the coordinate.
Tell the two kinds apart by type (``isinstance(field, TT)``). numpy only (the query path).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..discretization.coordinates import CoordinateInfo
from ..errors import CodebookError
from ..tensors.cp import CPTensor
from ..tensors.tt import TT

__all__ = ["CPTensor", "TT", "cp_field", "tt_field", "validate_field"]


def cp_field(name: str, weights, factors: Sequence) -> CPTensor:
    """The CP unknown ``name`` from its weights and one mode matrix per coordinate (CodebookError if malformed)."""
    try:
        return CPTensor(weights, factors)
    except ValueError as exc:
        raise CodebookError(f"unknown {name!r}: {exc}") from None


def tt_field(name: str, cores: Sequence, mode_order: Sequence[int]) -> TT:
    """The tensor-train unknown ``name`` from its cores and their coordinates (CodebookError if malformed)."""
    try:
        return TT(cores, mode_order)
    except ValueError as exc:
        raise CodebookError(f"unknown {name!r}: {exc}") from None


def _validate_tt(name: str, coordinates: Sequence[CoordinateInfo], field: TT) -> None:
    if len(field.cores) != len(coordinates):
        raise CodebookError(f"unknown {name!r}: tensor-train mode order {list(field.mode_order)} is not a "
                            f"permutation of the {len(coordinates)} coordinates")
    for k, (core, j) in enumerate(zip(field.cores, field.mode_order)):
        c = coordinates[j]
        if core.shape[1] != c.nodes:
            raise CodebookError(f"unknown {name!r}: core {k} ({c.name!r}) has shape {core.shape}, expected "
                                f"({core.shape[0]}, {c.nodes}, r)")
        if not np.all(np.isfinite(core)):
            raise CodebookError(f"unknown {name!r}: core {k} ({c.name!r}) contains non-finite values")


def validate_field(name: str, coordinates: Sequence[CoordinateInfo], field) -> None:
    """Check the unknown ``name`` against the coordinates: a CPTensor or TT with one mode per coordinate,
    as many nodes as the coordinate, finite values.

    Raises
    ------
    CodebookError
        Naming the unknown and the first mode (coordinate) that does not fit.
    """
    if isinstance(field, TT):
        _validate_tt(name, coordinates, field)
        return
    if not isinstance(field, CPTensor):
        raise CodebookError(f"unknown {name!r}: expected a CPTensor or a TT, got {type(field).__name__}")
    if len(field.factors) != len(coordinates):
        raise CodebookError(f"unknown {name!r}: {len(field.factors)} mode matrices for {len(coordinates)} "
                            f"coordinates")
    for j, (c, m) in enumerate(zip(coordinates, field.factors)):
        if m.shape != (c.nodes, field.rank):
            raise CodebookError(
                f"unknown {name!r}: modes of coordinate {j} ({c.name!r}) have shape {m.shape}, "
                f"expected ({c.nodes}, {field.rank})"
            )
    if not (np.all(np.isfinite(field.weights)) and all(np.all(np.isfinite(m)) for m in field.factors)):
        raise CodebookError(f"unknown {name!r}: alphas or modes contain non-finite values")
