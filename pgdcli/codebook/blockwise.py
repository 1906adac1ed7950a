"""A codebook evaluated on dask arrays, block by block (an analysis of 10^9 points on a cluster).

:meth:`pgdcli.Codebook.evaluate` hands coordinates of which one at least is a dask array here: they
are broadcast together (numbers and numpy arrays as dask arrays of one block), their blocks aligned,
and every block of points is one task evaluating the codebook on numpy arrays, the unknowns
stacked on a last axis that is then split per unknown. The codebook is one node of the graph
(``dask.delayed``): a cluster sends it to each worker once, not with every block. Nothing is
computed until the caller computes; a value outside a coordinate's domain is a
:class:`~pgdcli.errors.QueryError` then.

A block's values are those of :meth:`~pgdcli.Codebook.evaluate` on that block's numpy arrays.
"""

from __future__ import annotations

import uuid
from typing import Mapping

import numpy as np

__all__ = ["evaluate_blockwise"]


def evaluate_blockwise(codebook, coordinates: Mapping[str, object], selected: list[str]) -> dict:
    """``{unknown: dask array}`` of ``codebook`` at the coordinates (every name, codebook order).

    Parameters
    ----------
    codebook : pgdcli.Codebook
    coordinates : mapping of str to dask array, numpy array or number
        Broadcast together with numpy's rules.
    selected : list of str
        The unknowns, checked.

    Returns
    -------
    dict of str to dask.array.Array
        Of the broadcast shape, chunked as the aligned blocks of the coordinates.
    """
    import dask
    import dask.array as da

    names = list(coordinates)
    arrays = da.broadcast_arrays(*[da.asarray(np.asarray(v, dtype=float) if np.isscalar(v) else v, dtype=float)
                                   for v in coordinates.values()])
    index = "".join(chr(ord("a") + k) for k in range(arrays[0].ndim))
    pairs = [x for a in arrays for x in (a, index)]
    book = dask.delayed(codebook, pure=True, name=f"pgdcli-codebook-{uuid.uuid4().hex}")  # sent once
    stacked = da.blockwise(_block, index + "z", *pairs, book, None, names=names, selected=selected, dtype=float,
                           new_axes={"z": len(selected)}, meta=np.empty((0,) * (arrays[0].ndim + 1)))
    stacked = stacked.rechunk({arrays[0].ndim: len(selected)})
    return {u: stacked[..., k] for k, u in enumerate(selected)}


def _block(*args, names: list[str], selected: list[str]) -> np.ndarray:
    """One block: the codebook (last argument) at the blocks of the coordinates, unknowns stacked last."""
    *blocks, codebook = args
    values = codebook.evaluate(dict(zip(names, blocks)), selected)
    return np.stack([np.asarray(values[u], dtype=float) for u in selected], axis=-1)
