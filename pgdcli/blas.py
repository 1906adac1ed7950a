"""BLAS on one thread while a block of work runs: the package's one limiter.

Most of pgdcli's linear algebra is small dense products and factorizations (a core times a block
of points, the SVD of a supercore, the LU of a method of lines). Threaded BLAS gains little on
them, and when another process holds a core its threads spin waiting for each other: many times
slower. So the solvers, the references and large batch evaluations run with BLAS limited to one
thread (``threadpoolctl``).

The limit is process-wide, so it is shared: the first block to ask sets it, the last to end
lifts it (a count under a lock). Blocks may nest (a solve's check evaluates its codebook) and run
in threads of their own (the batch evaluation's chunks) without one lifting the other's limit.
numpy only at import: ``threadpoolctl`` is imported by the first block (``pgd query`` of a few
points never pays for it).
"""

from __future__ import annotations

import sys
import threading
from contextlib import contextmanager

__all__ = ["one_blas_thread", "limit_blas", "unlimit_blas", "blas_users"]

_lock = threading.Lock()
_controller = None  # threadpoolctl.ThreadpoolController: the BLAS libraries loaded when it was built
_modules_seen = -1  # len(sys.modules) then: a library loaded since (scipy's own BLAS) asks for a new one
_limiter = None  # the active one-thread limit, shared by the blocks running
_users = 0


def blas_users() -> int:
    """How many blocks hold the one-thread limit now (0 when none runs)."""
    return _users


@contextmanager
def one_blas_thread():
    """BLAS limited to one thread while the block runs (shared with the blocks running at the same time)."""
    limit_blas()
    try:
        yield
    finally:
        unlimit_blas()


def limit_blas() -> None:
    """Limit BLAS to one thread (process-wide) until the matching :func:`unlimit_blas`."""
    global _users, _limiter
    with _lock:
        if _users == 0:
            _limiter = _current_controller().limit(limits=1, user_api="blas")
            _release_control()
        _users += 1


def unlimit_blas() -> None:
    """End one :func:`limit_blas`; the last one restores the limits found before the first."""
    global _users, _limiter
    with _lock:
        _users -= 1
        if _users == 0:
            _limiter.restore_original_limits()
            _limiter = None
            _release_control()


def _current_controller():
    """The controller of the BLAS libraries loaded now (rebuilt when modules were imported since)."""
    global _controller, _modules_seen
    if _controller is None or len(sys.modules) != _modules_seen:
        from threadpoolctl import ThreadpoolController  # start-up: not on pgd query's path of one point

        _controller = ThreadpoolController()
        _modules_seen = len(sys.modules)
    return _controller


def _release_control() -> None:
    """Let any thread set OpenBLAS's (process-wide) limit next time.

    threadpoolctl >= 3.8 hands that limit to the first thread that sets it and silently ignores
    every other thread until the owner clears it; the limit here is shared by the blocks running
    and set or lifted, under the lock, by whichever thread comes first or ends last. Without this
    a batch run from a worker thread after one from the main thread ran with BLAS unlimited (and
    values differing in the last bit).
    """
    import threadpoolctl  # imported by _current_controller already

    clear = getattr(getattr(threadpoolctl, "OpenBLASController", None), "clear_controlling_thread", None)
    if clear is not None:
        clear(force=True)
