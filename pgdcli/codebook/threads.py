"""The thread and BLAS policy of batch evaluation, and the chunks it hands out.

Batches (CP and tensor-train) are cut into chunks of points, run in this thread or shared by
a few threads of our own, with BLAS limited to one thread while they run. The policy's
measurements: ``benchmarks/query_speed.py`` (its thread configurations). numpy only at import
(threadpoolctl on the first large batch).
"""

from __future__ import annotations

import os
import threading
from contextlib import contextmanager

__all__ = ["chunk_length", "chunk_bounds", "available_threads", "run_chunks", "one_blas_thread",
           "BLAS_LIMIT_MIN_POINTS", "PARALLEL_MIN_POINTS", "MAX_THREADS", "CHUNK_BYTES", "blas_users"]

# Batches are evaluated in chunks of points whose working set (two (chunk, total rank) blocks and
# two (chunk, nodes) blocks per coordinate) stays within a few MiB of cache. A batch of at most one
# chunk makes exactly the numpy/BLAS calls of the unchunked algorithm, so its values are bitwise
# those of that algorithm. Larger batches: chunk lengths are multiples of ROW_ALIGN, so every
# row keeps its position in the row blocks of the BLAS kernels; the kernel a product takes still
# depends on its shape (small-matrix kernels), so for some (nodes, rank) shapes a value can differ
# in the last bit from the unchunked product over all points -- as that product's own values
# depend on the number of points. One point takes a matrix-vector path.
# CHUNK_BYTES: one thread is as fast with smaller chunks, but two threads scale only with chunks
# this large, which hold the GIL for a smaller share of their time (benchmarks/query_speed.py).
ROW_ALIGN = 64
CHUNK_BYTES = 1 << 22
MAX_CHUNK = 4096
# BLAS thread policy per call site (benchmarks/query_speed.py measures each configuration).
# - One point, and batches under BLAS_LIMIT_MIN_POINTS: BLAS as is. A one-row product is far
#   below OpenBLAS's threading threshold, small batches cost little either way, and `pgd query`
#   on a few points is spared the threadpoolctl import.
# - Larger batches: BLAS limited to one thread (threadpoolctl) while they run. Threaded BLAS gains
#   little on these skinny products on idle cores, and is many times slower when another process
#   holds a core (its threads spin waiting for each other).
# - From PARALLEL_MIN_POINTS: chunks shared by up to MAX_THREADS threads of our own (numpy and
#   BLAS release the GIL): close to linear on idle cores, a few % slower when the cores are busy.
BLAS_LIMIT_MIN_POINTS = 512
PARALLEL_MIN_POINTS = 16384
MAX_THREADS = 8
_blas_lock = threading.Lock()
_blas_controller = None  # threadpoolctl.ThreadpoolController, built on first use; False: unavailable
_blas_limiter = None  # the active one-thread limit, shared by the batches running (_blas_users)
_blas_users = 0


def blas_users() -> int:
    """How many batches hold the one-thread BLAS limit now (0 when none runs)."""
    return _blas_users


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
    if size < BLAS_LIMIT_MIN_POINTS or not _limit_blas():
        run(iter(bounds))
        return
    try:
        threads = min(available_threads(), len(bounds)) if size >= PARALLEL_MIN_POINTS else 1
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
    finally:
        _unlimit_blas()


@contextmanager
def one_blas_thread(points: int):
    """BLAS limited to one thread while the block runs, for work on ``points`` points (from
    BLAS_LIMIT_MIN_POINTS; fewer: BLAS as is), shared with the batches running (see run_chunks)."""
    limited = points >= BLAS_LIMIT_MIN_POINTS and _limit_blas()
    try:
        yield
    finally:
        if limited:
            _unlimit_blas()


def _limit_blas() -> bool:
    """Limit BLAS to one thread (process-wide) until the matching :func:`_unlimit_blas`.

    Batches running at the same time share one limit, lifted when the last one
    ends. False (and no limit) if threadpoolctl is unavailable.
    """
    global _blas_controller, _blas_limiter, _blas_users
    with _blas_lock:
        if _blas_controller is None:
            try:
                from threadpoolctl import ThreadpoolController

                _blas_controller = ThreadpoolController()
            except Exception:  # pragma: no cover - threadpoolctl is a dependency
                _blas_controller = False
        if not _blas_controller:  # pragma: no cover
            return False
        if _blas_users == 0:
            _blas_limiter = _blas_controller.limit(limits=1, user_api="blas")
            _release_blas_control()
        _blas_users += 1
        return True


def _unlimit_blas() -> None:
    global _blas_limiter, _blas_users
    with _blas_lock:
        _blas_users -= 1
        if _blas_users == 0:
            _blas_limiter.restore_original_limits()
            _blas_limiter = None
            _release_blas_control()


def _release_blas_control() -> None:
    """Let any thread set OpenBLAS's (process-wide) limit next time.

    threadpoolctl >= 3.8 hands that limit to the first thread that sets it and
    silently ignores every other thread until the owner clears it; the limit
    here is shared by the batches running and set or lifted, under
    ``_blas_lock``, by whichever thread comes first or ends last. Without this a
    batch run from a worker thread after one from the main thread ran with
    BLAS unlimited (and values differing in the last bit).
    """
    import threadpoolctl  # imported by _limit_blas already

    clear = getattr(getattr(threadpoolctl, "OpenBLASController", None), "clear_controlling_thread", None)
    if clear is not None:
        clear(force=True)
