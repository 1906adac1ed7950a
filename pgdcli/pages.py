"""Float arrays in huge memory pages for tables read whole, and freed memory reused by a worker.

The kernel maps anonymous memory in 4 KiB pages, or in 2 MiB ones where asked (``madvise``)
and its transparent huge pages allow. numpy asks for huge pages for every array of 4 MiB and
more; a one-point query reads every core of a tensor-train codebook once (megabytes of tables for
a high-dimensional codebook), and smaller tables gain from huge pages too: their page walks go (a
few per cent of a point: ``benchmarks/query_speed_tt.py``'s single-point rows). Where the platform
has no ``madvise`` flags (not Linux) the table is a plain numpy array.

Freed memory is the other case: :func:`reuse_freed_memory` lets a worker process reuse the blocks
that numpy frees (a march's stages, a batch's results) instead of returning them to the kernel and
faulting fresh zeroed pages in at every allocation.
"""

from __future__ import annotations

import ctypes
import mmap

import numpy as np

__all__ = ["HUGE_PAGE", "huge_page_array", "reuse_freed_memory"]

HUGE_PAGE = 1 << 21  # bytes (x86-64 and arm64 with 4 KiB base pages)
#: Blocks up to this size come from the heap, not from a mapping of their own (glibc's largest
#: automatic threshold on 64-bit systems); the heap keeps twice as much free before giving it back.
MMAP_THRESHOLD = 1 << 25


def huge_page_array(values: int) -> np.ndarray:
    """An uninitialized float array of ``values`` values starting on a huge-page boundary, in a
    private anonymous mapping advised to use huge pages (whole huge pages: the mapping is rounded up).

    Parameters
    ----------
    values : int

    Returns
    -------
    ndarray, shape (values,)
        A view of the mapping (which lives as long as any view of it).
    """
    if not hasattr(mmap, "MADV_HUGEPAGE") or not hasattr(mmap, "MAP_PRIVATE"):
        return np.empty(values)
    used = -(-values * 8 // HUGE_PAGE) * HUGE_PAGE  # whole huge pages: a partial one stays in small pages
    mapping = mmap.mmap(-1, used + HUGE_PAGE, flags=mmap.MAP_PRIVATE)  # + one page to align the start
    mapping.madvise(mmap.MADV_HUGEPAGE)
    raw = np.frombuffer(mapping, dtype=np.uint8)
    start = -raw.ctypes.data % HUGE_PAGE
    return raw[start:start + values * 8].view(np.float64)


def reuse_freed_memory() -> bool:
    """Let glibc's allocator keep freed blocks of up to :data:`MMAP_THRESHOLD` bytes for reuse.

    glibc raises its mmap threshold as a process frees large blocks, so that arrays freed and
    allocated again (a batch of nodes marched step after step) reuse the same memory. Setting any
    of its thresholds in the environment turns that off, and Dask's nanny does so for its workers
    (``MALLOC_TRIM_THRESHOLD_``, to return memory to the system at once): every array above
    128 KiB is then a fresh mapping whose pages are faulted in and zeroed, which makes a march in
    a worker several times slower than here. The thresholds set here are the ones glibc reaches by
    itself in a process that runs the same work.

    Returns
    -------
    bool
        Whether the allocator took them (False where it is not glibc's).
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own symbols: glibc's where it is the C library
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    return bool(mallopt(m_mmap_threshold, MMAP_THRESHOLD)) and bool(mallopt(m_trim_threshold, 2 * MMAP_THRESHOLD))
