"""The two stored forms of an unknown: separated sum (CP) and tensor train, with their checks.

A codebook field holds nodal values: ``FieldModes`` (weights and one mode matrix per
coordinate, TensorLy's ``CPTensor`` layout) or ``FieldTT`` (cores in a coordinate order).
Tell them apart by type (``isinstance(fm, FieldTT)``). numpy only (the query path).

Why ``FieldModes`` is not :class:`pgdcli.tensors.cp.CPTensor` (the same layout): ``tensors/cp.py``
imports scipy at module level (LAPACK's geqrf for its orthogonal sweeps), and this module is on
``pgd query``'s path, whose start-up must stay close to that of ``python -c "import numpy, h5py"``
(importing scipy.linalg would dominate it: ``benchmarks/query_speed.py``). ``CPTensor`` also
raises ValueError where a codebook file must give a CodebookError naming the unknown
(:func:`validate_field`). One type would need the ``CPTensor`` dataclass in a numpy-only module
of ``tensors/`` (then ``FieldModes`` its subclass with ``alphas``/``modes`` as names of
``weights``/``factors``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..discretization.coordinates import CoordinateInfo
from ..errors import CodebookError

__all__ = ["FieldModes", "FieldTT", "validate_field"]


@dataclass(frozen=True, eq=False)
class FieldModes:
    """Separated representation of one unknown (weights + one mode matrix per coordinate).

    Parameters
    ----------
    alphas : ndarray, shape (n,)
    modes : tuple of ndarray, each shape (nodes_j, n)
    """

    alphas: np.ndarray
    modes: tuple[np.ndarray, ...]

    @property
    def rank(self) -> int:
        return int(self.alphas.size)


@dataclass(frozen=True, eq=False)
class FieldTT:
    """Tensor-train representation of one unknown (the nonlinear solver's codebooks).

    ``u(x) = G_1[:, x_{o_1}, :] G_2[:, x_{o_2}, :] ... G_d[:, x_{o_d}, :]`` where the
    cores are in the coordinate order ``mode_order`` and each core's middle
    index runs over the nodes of its coordinate (interpolated like the CP modes).

    Parameters
    ----------
    cores : tuple of ndarray, each shape (r_{k-1}, nodes, r_k), r_0 = r_d = 1
    mode_order : tuple of int
        Coordinate index of each core.
    """

    cores: tuple[np.ndarray, ...]
    mode_order: tuple[int, ...]

    @property
    def rank(self) -> int:
        """Largest tensor-train rank (reported as 'modes' for a quick comparison)."""
        return int(max(c.shape[2] for c in self.cores[:-1])) if len(self.cores) > 1 else 1

    @property
    def ranks(self) -> tuple[int, ...]:
        return tuple(int(c.shape[2]) for c in self.cores[:-1])

    @property
    def size(self) -> int:
        return int(sum(c.size for c in self.cores))


def _validate_tt(name: str, coordinates: Sequence[CoordinateInfo], fm: FieldTT) -> None:
    if sorted(fm.mode_order) != list(range(len(coordinates))):
        raise CodebookError(f"unknown {name!r}: tensor-train mode order {list(fm.mode_order)} is not a permutation "
                            f"of the {len(coordinates)} coordinates")
    left = 1
    for k, (core, j) in enumerate(zip(fm.cores, fm.mode_order)):
        c = coordinates[j]
        if core.ndim != 3 or core.shape[0] != left or core.shape[1] != c.nodes:
            raise CodebookError(f"unknown {name!r}: core {k} ({c.name!r}) has shape {core.shape}, expected "
                                f"({left}, {c.nodes}, r)")
        left = core.shape[2]
        if not np.all(np.isfinite(core)):
            raise CodebookError(f"unknown {name!r}: core {k} ({c.name!r}) contains non-finite values")
    if left != 1:
        raise CodebookError(f"unknown {name!r}: the last core's right rank is {left}, expected 1")


def validate_field(name: str, coordinates: Sequence[CoordinateInfo], fm) -> None:
    if isinstance(fm, FieldTT):
        _validate_tt(name, coordinates, fm)
        return
    if fm.alphas.ndim != 1:
        raise CodebookError(f"unknown {name!r}: alphas must be 1D, got shape {fm.alphas.shape}")
    if len(fm.modes) != len(coordinates):
        raise CodebookError(f"unknown {name!r}: {len(fm.modes)} mode matrices for {len(coordinates)} coordinates")
    for j, (c, m) in enumerate(zip(coordinates, fm.modes)):
        if m.shape != (c.nodes, fm.rank):
            raise CodebookError(
                f"unknown {name!r}: modes of coordinate {j} ({c.name!r}) have shape {m.shape}, "
                f"expected ({c.nodes}, {fm.rank})"
            )
    if not (np.all(np.isfinite(fm.alphas)) and all(np.all(np.isfinite(m)) for m in fm.modes)):
        raise CodebookError(f"unknown {name!r}: alphas or modes contain non-finite values")
