"""The thread and BLAS policy of batch evaluation, and the chunks it hands out.

Batches (CP and tensor-train) are cut into chunks of points, run in this thread or shared by
a few threads of our own, with BLAS limited to one thread while they run
(:func:`pgdcli.blas.one_blas_thread`). The sizes are :mod:`pgdcli.tuning`'s; the policy's
measurements: ``benchmarks/query_speed.py`` (its thread configurations). numpy only at import
(threadpoolctl on the first large batch).

A batch of at most one chunk makes exactly the numpy/BLAS calls of the unchunked algorithm.
Larger batches: chunk lengths are multiples of ROW_ALIGN, so every row keeps its position in the
row blocks of the BLAS kernels; the kernel a product takes still depends on its shape
(small-matrix kernels), so for some (nodes, rank) shapes a value can differ in the last bit from
the unchunked product over all points -- as that product's own values depend on the number of
points. One point takes a matrix-vector path.

The BLAS policy per call site:

- One point, and batches under BLAS_LIMIT_MIN_POINTS: BLAS as is. A one-row product is far below
  OpenBLAS's threading threshold, small batches cost little either way, and ``pgd query`` on a
  few points is spared the threadpoolctl import.
- Larger batches, grids and series: BLAS limited to one thread while they run.
- From PARALLEL_MIN_POINTS: chunks shared by up to MAX_THREADS threads of our own (numpy and
  BLAS release the GIL).
"""

from __future__ import annotations

import os
import threading
from contextlib import nullcontext

from ..blas import blas_users, one_blas_thread
from ..tuning import BLAS_LIMIT_MIN_POINTS, CHUNK_BYTES, MAX_CHUNK, MAX_THREADS, PARALLEL_MIN_POINTS

__all__ = ["chunk_length", "chunk_bounds", "available_threads", "run_chunks", "batch_blas",
           "BLAS_LIMIT_MIN_POINTS", "PARALLEL_MIN_POINTS", "MAX_THREADS", "CHUNK_BYTES", "blas_users"]

ROW_ALIGN = 64  # rows per block of the BLAS kernels' row blocks


def chunk_length(rank: int, nodes: int) -> int:
    """Points per chunk for ``rank`` values and ``nodes`` rows per point (see the notes above)."""
    rows = CHUNK_BYTES // (16 * (rank + nodes))
    return min(MAX_CHUNK, max(ROW_ALIGN, rows // ROW_ALIGN * ROW_ALIGN))


def chunk_bounds(size: int, chunk: int) -> list[tuple[int, int]]:
    """``[lo, hi)`` ranges of ``chunk`` points covering ``range(size)``; a last range of one point
    joins the one before (a one-row product would take a matrix-vector path)."""
    edges = list(range(0, size, chunk)) + [size]
    if len(edges) > 2 and edges[-1] - edges[-2] == 1:
        del edges[-2]
    return list(zip(edges[:-1], edges[1:]))


def available_threads() -> int:
    """Threads a large batch may use: the cores this process may run on, at most MAX_THREADS."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    return max(1, min(n, MAX_THREADS))


def run_chunks(run, bounds: list[tuple[int, int]]) -> None:
    """``run(iterator of bounds)``, with the BLAS and thread policy above."""
    size = bounds[-1][1]
    if size < BLAS_LIMIT_MIN_POINTS:
        run(iter(bounds))
        return
    threads = min(available_threads(), len(bounds)) if size >= PARALLEL_MIN_POINTS else 1
    with one_blas_thread():
        if threads <= 1:
            run(iter(bounds))
            return
        todo = iter(bounds)  # shared: a thread takes the next chunk when it is done with one
        errors = []

        def guarded():
            try:
                run(todo)
            except BaseException as exc:  # re-raised in the calling thread
                errors.append(exc)

        workers = [threading.Thread(target=guarded, daemon=True) for _ in range(threads - 1)]
        for w in workers:
            w.start()
        guarded()
        for w in workers:
            w.join()
        if errors:
            raise errors[0]


def batch_blas(points: int):
    """A context in which BLAS runs on one thread for work on ``points`` points (from
    BLAS_LIMIT_MIN_POINTS; fewer: BLAS as is), shared with the batches running (see run_chunks)."""
    return one_blas_thread() if points >= BLAS_LIMIT_MIN_POINTS else nullcontext()
