"""Machine-specific tuning: every constant chosen for a machine's caches, cores or memory, in one place.

Each constant sets how work is cut up (points per block, bytes per chunk, threads) or when a
faster path pays (a size threshold, a cost model's seconds), never the method or its tolerances:
results agree with those of any other setting to rounding (a product's summation order can
depend on its shape). The defaults were measured on a 2-core x86-64 machine with 32 KiB of first-level and
1 MiB of second-level cache per core (``benchmarks/query_speed.py``,
``benchmarks/query_speed_tt.py``, ``benchmarks/README.md``); another machine may do better with
others. Each is read once, at import, from the environment variable ``PGD_<NAME>`` when it is
set (e.g. ``PGD_MAX_THREADS=1``); a value that is not a positive number of the constant's kind
raises :class:`~pgdcli.errors.PgdError` naming the variable. ``docs/tuning.md`` lists them for users.

The modules that use a constant import it from here (``from ..tuning import BLOCK_BYTES``), so a
test or benchmark may still set the module's own name for a run.
"""

from __future__ import annotations

import os

from .errors import PgdError

__all__ = ["SETTINGS", "setting"]

#: name -> (default, what it sets); the module constants below are these, or their overrides.
SETTINGS: dict[str, tuple[int | float, str]] = {}


def setting(name: str, default: int | float, meaning: str) -> int | float:
    """``default``, or the value of the environment variable ``PGD_<name>`` (same kind, positive)."""
    SETTINGS[name] = (default, meaning)
    variable = f"PGD_{name}"
    text = os.environ.get(variable)
    if text is None:
        return default
    kind = "integer" if isinstance(default, int) else "number"
    try:
        value = int(text) if isinstance(default, int) else float(text)
    except ValueError:
        value = None
    if value is None or not value > 0 or value == float("inf"):
        raise PgdError(f"environment variable {variable}: expected a positive {kind} ({meaning}; default "
                       f"{default!r}), got {text[:40]!r}")
    return value


# ------------------------------------------------------------------ batches: chunks, BLAS, threads
# (pgdcli.codebook.threads) A chunk's working set, two (chunk, total rank) and two (chunk, nodes)
# blocks per coordinate, stays within a few MiB of cache; one thread is as fast with smaller chunks,
# but two threads scale only with chunks this large, which hold the GIL for a smaller share of
# their time (benchmarks/query_speed.py).
CHUNK_BYTES = setting("CHUNK_BYTES", 1 << 22, "bytes of a CP batch's chunk of points (its working set)")
MAX_CHUNK = setting("MAX_CHUNK", 4096, "most points in a CP batch's chunk")
# Threaded BLAS gains little on these skinny products on idle cores, and is many times slower when
# another process holds a core (its threads spin waiting for each other).
BLAS_LIMIT_MIN_POINTS = setting("BLAS_LIMIT_MIN_POINTS", 512,
                                "points from which a batch, grid or series runs with BLAS on one thread")
# numpy and BLAS release the GIL: chunks shared by threads of our own scale close to linearly on
# idle cores, a few % slower when the cores are busy.
PARALLEL_MIN_POINTS = setting("PARALLEL_MIN_POINTS", 16384, "points from which a batch's chunks are shared by threads")
MAX_THREADS = setting("MAX_THREADS", 8, "most threads a batch uses, never more than the cores this process may use")

# ------------------------------------------------------------------ tensor-train batches
# (pgdcli.codebook.batch_eval) A block's widest intermediate (points x values per point) within
# the second-level cache, the scratch buffers reused at every block; more points per block
# amortize the few dozen numpy calls of a block (block sizes timed side by side with
# benchmarks/query_speed_tt.py).
BLOCK_BYTES = setting("BLOCK_BYTES", 3 << 19, "bytes of a tensor-train batch's widest intermediate per block")
MIN_BLOCK = setting("MIN_BLOCK", 32, "fewest points in a tensor-train batch's block")
MAX_BLOCK = setting("MAX_BLOCK", 2048, "most points in a tensor-train batch's block")
# The cost model that decides whether points are grouped by a later coordinate's windows (slabs,
# linear elements): seconds per multiply-add in the blocks' products (one core's AVX2 rate) and per
# block of points (its few dozen numpy calls), both from the batch rows of
# benchmarks/query_speed_tt.py with more and fewer blocks.
SECONDS_PER_MADD = setting("SECONDS_PER_MADD", 4e-11, "seconds per multiply-add of a batch's block products")
SECONDS_PER_BLOCK = setting("SECONDS_PER_BLOCK", 4e-5, "seconds of overhead per block of a batch")
MAX_PAIR_VALUES = setting("MAX_PAIR_VALUES", 1 << 22,
                          "most values of a batch's merged first-two-core table (all windows and unknowns)")

# ------------------------------------------------------------------ one point
# (pgdcli.codebook.point) A core's node table is read through by a matrix-vector product whose
# output fits the first-level cache (32 KiB) up to this many values per node; larger cores are
# contracted with the running vector first.
ROW_FIRST_MAX = setting("ROW_FIRST_MAX", 4096, "most values per node of a core read through its node table")
PAIR_MAX = setting("PAIR_MAX", 1 << 20, "most values of the one-point path's merged table of two cores")
# A point reads every table once; in 4 KiB pages their page walks cost a few % of a point.
HUGE_PAGES_ABOVE = setting("HUGE_PAGES_ABOVE", 1 << 20, "bytes of the one-point tables above which they lie in huge pages")

# ------------------------------------------------------------------ gradients
# (pgdcli.codebook.gradient) A march's time basis has ~1e4-1e5 nodes: the dense rows of a large
# batch of points are built a block at a time.
CHUNK_VALUES = setting("CHUNK_VALUES", 1 << 22, "values of one coordinate's rows built at once by a gradient")

# ------------------------------------------------------------------ cross approximation
# (pgdcli.tensors.fiber_cross) Below glibc's largest mmap threshold (32 MB) the arrays of
# successive calls reuse memory instead of faulting pages in. A call is a task on a cluster: batches
# of a few thousand trajectories march as fast per node as larger ones, and a half sweep's calls
# then give every worker of a small cluster its share (benchmarks/cluster_scaling.py).
BATCH_FLOATS = setting("BATCH_FLOATS", 2 ** 20, "values asked of a fibre cross's function in one call")
MEMO_FLOATS = setting("MEMO_FLOATS", 2 ** 26, "values a fibre cross keeps (with their keys) to answer one asked again")
