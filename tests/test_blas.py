"""pgdcli.blas: one shared limit of BLAS to one thread, nested, from threads, and for libraries loaded late."""

from __future__ import annotations

import subprocess
import sys
import threading

import threadpoolctl

from pgdcli import blas


def _blas_threads() -> list[int]:
    return [m["num_threads"] for m in threadpoolctl.threadpool_info() if m["user_api"] == "blas"]


def test_blocks_share_one_limit_lifted_by_the_last(two_blas_threads):
    before = _blas_threads()
    assert set(before) == {2}
    with blas.one_blas_thread():
        assert blas.blas_users() == 1 and set(_blas_threads()) == {1}
        with blas.one_blas_thread():
            assert blas.blas_users() == 2 and set(_blas_threads()) == {1}
        assert blas.blas_users() == 1 and set(_blas_threads()) == {1}  # the inner block left it on
    assert blas.blas_users() == 0 and _blas_threads() == before


def test_a_block_in_another_thread_keeps_the_limit(two_blas_threads):
    seen = []

    def worker():
        with blas.one_blas_thread():
            seen.append(set(_blas_threads()))

    with blas.one_blas_thread():
        t = threading.Thread(target=worker)
        t.start()
        t.join()
        seen.append(set(_blas_threads()))
    assert seen == [{1}, {1}] and blas.blas_users() == 0


def test_the_limit_reaches_a_library_loaded_after_the_first_block():
    """numpy's BLAS limited first, then scipy (which may bring a BLAS of its own) imported: both limited."""
    code = (
        "import numpy, threadpoolctl\n"
        "from pgdcli.blas import one_blas_thread\n"
        "with one_blas_thread():\n"
        "    pass\n"
        "import scipy.linalg\n"
        "with one_blas_thread():\n"
        "    print(sorted({m['num_threads'] for m in threadpoolctl.threadpool_info() if m['user_api'] == 'blas'}))\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[1]"
